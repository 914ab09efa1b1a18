"""Instance recognition at a category estimate (Sec. III-B, Eqs. 5-6).

Eq. 5 scores instance ``l`` at the category estimate ``w*`` by how well its
own model density explains the test features,
``p_l(w*) ~ 1/n sum_j psi_l(w*, x_j)``. Here the sum runs over the ``n`` test
features inside the estimated object box (clutter outside it would add the
same nothing to every instance), and each term is the instance's
appearance density at ``x_j``, normalised so that a test point lying on one
of the model's contours scores 1, and saturated at 1 (a test point is
explained or not). An instance whose model lacks a detail the image shows
(a spoiler, a label) loses those points; one that matches everywhere keeps
them all. The counterpart, the fraction of the model explained by the image
(the search score), cannot tell an instance from a plainer one whose
features it contains.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from posevote.features.edges import EdgeFeatures
from posevote.geometry import rotate_points
from posevote.model.density import PoseModel
from posevote.results import Hypothesis
from posevote.scoring.score import explained_sums, viewpoint_features


def explained_fraction(test: EdgeFeatures, model: PoseModel, hypothesis: Hypothesis, *,
                       box: tuple[float, float, float, float] | None = None,
                       position_sigma: float, orientation_kappa: float, viewpoint_kappa: float,
                       use_weights: bool = True, k1_cutoff: float = 0.1,
                       box_margin: float = 0.1) -> float:
    """Fraction of the test features in the object's box explained by a model at a pose.

    Parameters
    ----------
    test : EdgeFeatures
        The test image's features, pixels.
    model : PoseModel
        One instance's model.
    hypothesis : Hypothesis
        The pose at which to place the model.
    box : (x, y, w, h), optional
        The box whose test features are explained (default: the
        hypothesis's box); give several instances the same box to compare
        them.
    position_sigma, orientation_kappa : float
        Appearance kernel widths, pixels.
    viewpoint_kappa, use_weights, k1_cutoff
        As in :func:`posevote.scoring.score.viewpoint_features`.
    box_margin : float, optional
        The box is grown by this fraction of its size on each side.

    Returns
    -------
    float
        In ``[0, 1]``; 0 when the box holds no test feature.
    """
    x, y, w, h = hypothesis.box if box is None else box
    grow_x, grow_y = box_margin * w, box_margin * h
    inside = ((test.xy[:, 0] >= x - grow_x) & (test.xy[:, 0] <= x + w + grow_x)
              & (test.xy[:, 1] >= y - grow_y) & (test.xy[:, 1] <= y + h + grow_y))
    if not inside.any():
        return 0.0
    feats = viewpoint_features(model, hypothesis.azimuth, hypothesis.elevation,
                               viewpoint_kappa=viewpoint_kappa, use_weights=use_weights,
                               k1_cutoff=k1_cutoff)
    if len(feats.theta) == 0:
        return 0.0
    xy = hypothesis.scale * rotate_points(feats.xy, hypothesis.inplane) \
        + np.asarray(hypothesis.position)
    theta = np.mod(feats.theta + hypothesis.inplane, np.pi)
    strength = feats.weight / feats.weight.max()
    # Spacing of the model's points along its contours, in image pixels: a
    # test point on a contour then sums to about sqrt(2 pi) sigma / spacing.
    spacing = median_spacing(xy)
    gain = max(spacing, 1e-6) / (np.sqrt(2.0 * np.pi) * position_sigma)
    total = explained_sums(xy, theta, strength, test.xy[inside], test.theta[inside],
                           position_sigma, orientation_kappa)
    return float(np.mean(np.minimum(gain * total, 1.0)))


@numba.njit(cache=True, nogil=True)
def _nearest_distances(xy, order):  # pragma: no cover - compiled
    """Each point's distance to its nearest other point; ``order`` sorts the points by x."""
    n = xy.shape[0]
    out = np.full(n, np.inf)
    for k in range(n):
        i = order[k]
        best = np.inf
        for step in (-1, 1):
            m = k + step
            while 0 <= m < n:
                j = order[m]
                dx = xy[j, 0] - xy[i, 0]
                if dx * dx >= best:
                    break
                d = dx * dx + (xy[j, 1] - xy[i, 1]) ** 2
                if d < best:
                    best = d
                m += step
        out[i] = np.sqrt(best)
    return out


def median_spacing(xy: NDArray[np.float64]) -> float:
    """Median distance from each point to its nearest other point (1 for fewer than two)."""
    if len(xy) < 2:
        return 1.0
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    return float(np.median(_nearest_distances(xy, np.argsort(xy[:, 0], kind="stable"))))


def median_spacing_reference(xy: NDArray[np.float64]) -> float:
    """:func:`median_spacing` by a k-d tree (for tests)."""
    from scipy.spatial import cKDTree

    return float(np.median(cKDTree(xy).query(xy, k=2)[0][:, 1])) if len(xy) > 1 else 1.0


def recognition_margin(scores: NDArray[np.float64]) -> tuple[int, float]:
    """The best instance and its score over the runner-up's (inf if that is 0)."""
    order = np.argsort(-scores, kind="stable")
    if len(order) < 2:
        return int(order[0]), float("inf")
    second = float(scores[order[1]])
    return int(order[0]), (float(scores[order[0]]) / second if second > 0 else float("inf"))
