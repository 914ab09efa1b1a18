"""The found pose checked against its half-turn (beyond the paper).

Seen from behind, an object often shows the outline it shows from the front,
and where one side carries fewer edges than the other (a plain back, a
detailed face) its edges are nearly a subset of the other side's. The
narrow score is the share of the model that the image explains, so the
plainer side placed over the other explains itself as fully as the right
pose does, and a search over a range of scales also finds the size where
its outline fits (the rendered sphere's r2d2: its back at about 0.85 of the
scale of its face). What tells them apart is the other direction: the share
of the test edges inside the two poses' outlines that each pose's features
explain (:func:`edge_share`).

:func:`half_turn` polishes the found pose's half-turn (azimuth plus 180
degrees, the elevation kept) from :data:`HALF_TURN_SCALES` times its scale,
keeps the polish whose narrow score times template correlation is highest,
and scores it and the found pose (polished on the same maps) by that product
times their share of the test edges. The half-turn replaces the found pose
where it scores higher. It runs with the template re-ranking and the local
refinement (the ``cluttered`` preset); docs/DEFAULTS.md, "Half-turn check",
has the measurements.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from posevote.geometry import rotate_points
from posevote.inference.coverage import MIN_BOX_EDGES
from posevote.inference.maps import TestMaps
from posevote.inference.search import SearchSetup, ViewpointFeatures, viewpoint_features
from posevote.inference.templates import CORRELATION_FLOOR
from posevote.model.density import PoseModel
from posevote.model.kernels import (
    K1_CUTOFF,
    ORIENTATION_KAPPA,
    orientation_kernel,
    position_kernel,
)
from posevote.model.outline import box_outline, inside_outline, outline_at
from posevote.refinement.local import polish_pose
from posevote.results import Hypothesis

#: Scales, relative to the found pose's, that the half-turn's polishes start
#: from: a side framed differently is found at another size (docs/DEFAULTS.md).
HALF_TURN_SCALES = (0.85, 1.0, 1 / 0.85)
#: Pairs of edges further apart than this many kernel widths add nothing.
_REACH_SIGMAS = 4.0
#: Model features at which its typical density on itself is read (evenly spaced).
_TYPICAL_POINTS = 256


def _features(hypothesis: Hypothesis, model: PoseModel, setup: SearchSetup
              ) -> ViewpointFeatures:
    return viewpoint_features(model, hypothesis.azimuth, hypothesis.elevation,
                              viewpoint_kappa=setup.viewpoint_kappa,
                              use_weights=setup.use_weights, k1_cutoff=K1_CUTOFF)


def _inside(hypothesis: Hypothesis, model: PoseModel, points: NDArray[np.float64],
            setup: SearchSetup, features: ViewpointFeatures) -> NDArray[np.bool_]:
    """Which points lie inside the pose's outline (its views' box where the model has none)."""
    outline = outline_at(model, hypothesis.azimuth, hypothesis.elevation,
                         kappa=setup.viewpoint_kappa, k1_cutoff=K1_CUTOFF)
    if outline is None:
        outline = box_outline(features.box)
    return inside_outline(points, outline, hypothesis.position, hypothesis.scale,
                          hypothesis.inplane)


def _density(at_xy: NDArray[np.float64], at_theta: NDArray[np.float64],
             xy: NDArray[np.float64], theta: NDArray[np.float64], sigma: float
             ) -> NDArray[np.float64]:
    """The kernel density of the edges ``xy``, ``theta`` at each point, unnormalised."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(at_xy).sparse_distance_matrix(cKDTree(xy), _REACH_SIGMAS * sigma,
                                                  output_type="ndarray")
    i, j, d = pairs["i"], pairs["j"], pairs["v"]
    value = position_kernel(d * d, sigma) * orientation_kernel(at_theta[i] - theta[j],
                                                              ORIENTATION_KAPPA)
    return np.asarray(np.bincount(i, weights=value, minlength=len(at_xy)), dtype=np.float64)


def edge_share(hypothesis: Hypothesis, model: PoseModel, maps: TestMaps,
               selected: NDArray[np.bool_], setup: SearchSetup, *,
               features: ViewpointFeatures | None = None) -> float:
    """The share of the selected test edges that the pose's features explain.

    As :func:`posevote.inference.coverage.coverage` reads it (the placed
    model's density at each test edge over its typical density on its own
    features, capped at 1, averaged), but summed exactly rather than read
    from a grid: the half-turn's decision turns on a few percent.

    Parameters
    ----------
    hypothesis : Hypothesis
        In the frame of ``maps`` (image pixels).
    model : PoseModel
    maps : TestMaps
        The test edges (``xy``, ``theta``) and the narrow kernel's width.
    selected : ndarray of bool, shape (N,)
        The test edges counted.
    setup : SearchSetup
    features : ViewpointFeatures, optional
        The pose's viewpoint features, if already collected.

    Returns
    -------
    float
        In [0, 1]; 0 with fewer than
        :data:`~posevote.inference.coverage.MIN_BOX_EDGES` edges selected.
    """
    if selected.sum() < MIN_BOX_EDGES:
        return 0.0
    feats = _features(hypothesis, model, setup) if features is None else features
    if len(feats.xy) == 0:
        return 0.0
    xy = hypothesis.scale * rotate_points(feats.xy, hypothesis.inplane) + np.asarray(
        hypothesis.position, dtype=np.float64)
    theta = np.mod(feats.theta + hypothesis.inplane, np.pi)
    sigma = float(maps.position_sigma)
    # Its typical density on itself (a pooled model stacks several views on each
    # contour) and its density at the test edges, in one pass.
    own = np.arange(0, len(xy), max(1, len(xy) // _TYPICAL_POINTS))
    density = _density(np.concatenate([xy[own], maps.xy[selected]]),
                       np.concatenate([theta[own], maps.theta[selected]]), xy, theta, sigma)
    typical = float(np.median(density[:len(own)]))
    if not typical > 0:
        return 0.0
    return float(np.mean(np.minimum(density[len(own):] / typical, 1.0)))


def half_turn(hypothesis: Hypothesis, model: PoseModel, maps: TestMaps, setup: SearchSetup,
              correlate: Callable[[list[Hypothesis]], NDArray[np.float64]]) -> Hypothesis:
    """The found pose, or its half-turn where that explains the image better.

    Parameters
    ----------
    hypothesis : Hypothesis
        The refined pose (image pixels).
    model : PoseModel
    maps : TestMaps
        The test image's narrow maps in image pixels
        (:func:`posevote.inference.search.image_maps`).
    setup : SearchSetup
    correlate : callable
        Each pose's correlation with the object's grey levels
        (:func:`posevote.inference.templates.pose_correlations`).

    Returns
    -------
    Hypothesis
        ``hypothesis`` itself, or the polished half-turn scored by its narrow
        score times its correlation (as the local refinement scores).
    """
    opts: dict[str, Any] = {"viewpoint_kappa": setup.viewpoint_kappa,
                            "use_weights": setup.use_weights, "k1_cutoff": K1_CUTOFF}
    found = polish_pose(hypothesis, model, maps, **opts)
    turned = float(np.mod(hypothesis.azimuth + np.pi, 2.0 * np.pi))
    candidates = [polish_pose(replace(hypothesis, azimuth=turned, scale=hypothesis.scale * f),
                              model, maps, **opts) for f in HALF_TURN_SCALES]
    poses = [found, *candidates]
    product = np.array([h.score for h in poses]) * np.maximum(correlate(poses),
                                                              CORRELATION_FLOOR)
    best = 1 + int(np.argmax(product[1:]))
    other = poses[best]
    if not product[best] > 0:
        return hypothesis
    found_feats, other_feats = _features(found, model, setup), _features(other, model, setup)
    # The edges inside either outline: the object's, wherever either pose puts it.
    selected = (_inside(found, model, maps.xy, setup, found_feats)
                | _inside(other, model, maps.xy, setup, other_feats))
    share = edge_share(found, model, maps, selected, setup, features=found_feats)
    # A share is at most 1: the half-turn cannot win unless its product beats this.
    if product[best] <= product[0] * share:
        return hypothesis
    if product[best] * edge_share(other, model, maps, selected, setup,
                                  features=other_feats) > product[0] * share:
        return replace(other, score=float(product[best]), refined=True)
    return hypothesis
