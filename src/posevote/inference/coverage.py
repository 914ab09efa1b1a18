"""The search's best probes re-ranked by how much of the image they explain.

The vote scores a probe by what share of the model its image edges explain
(model to image). A model shrunk inside the object's own texture, or turned
half round, can explain as much of itself as the right pose does, while
leaving many of the edges in its box unexplained. The coverage of a probe is
the other direction: the share of the test edges inside its box that its
model features explain, each counted at most once. The best
:data:`COVERAGE_CANDIDATES` probes have their score multiplied by their
coverage; every other probe by the lowest of those coverages, so that the
others keep their order below them (beyond the paper; docs/DEFAULTS.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from posevote.features.edges import EdgeFeatures
from posevote.geometry import rotate_points
from posevote.inference.probes import ProbeSet
from posevote.inference.setup import SearchSetup
from posevote.model.density import PoseModel
from posevote.model.kernels import K1_CUTOFF, ORIENTATION_KAPPA
from posevote.scoring.maps import TestMaps, prepare_test
from posevote.scoring.score import MIN_BOX_EDGES, density_at, viewpoint_features

#: Probes re-ranked: chosen on the five epfl-cv folds among 6, 12, 30 and 60
#: (docs/DEFAULTS.md).
COVERAGE_CANDIDATES = 12
_FLOOR = 1e-6
#: Width of the model's density kernel in cells of its coarse grid.
COARSE_KERNEL = 2.0


def coverage(model_xy: NDArray[np.float64], model_theta: NDArray[np.float64],
             maps: TestMaps, box: NDArray[np.float64], centre: NDArray[np.float64], *,
             edge_spacing: float) -> float:
    """The share of the test edges in a box that the placed model explains.

    Parameters
    ----------
    model_xy, model_theta : ndarray
        The model features already placed in the maps' frame (pixels, radians).
    maps : TestMaps
        The test features (and the position kernel width, ``position_sigma``).
    box : ndarray, shape (2,)
        Box width and height in the maps' frame.
    centre : ndarray, shape (2,)
        Its centre.
    edge_spacing : float
        Spacing of the model features along their edges, in the maps' frame.

    Returns
    -------
    float
        In [0, 1]: the mean over the test edges in the box of the model's
        density there, relative to its typical density on its own features
        and capped at 1.
    """
    lo, hi = centre - box / 2.0, centre + box / 2.0
    inside = np.all((maps.xy >= lo) & (maps.xy <= hi), axis=1)
    if inside.sum() < MIN_BOX_EDGES or len(model_xy) == 0:
        return 0.0
    # The model's density is smooth at the kernel's width: tabulated with the
    # kernel COARSE_KERNEL cells wide, on a coarser grid than the maps' pixels.
    cell = max(1.0, maps.position_sigma / COARSE_KERNEL)
    pad = 3.0 * maps.position_sigma
    origin = lo - pad
    shape = (int(np.ceil((box[1] + 2 * pad) / cell)) + 1, int(np.ceil((box[0] + 2 * pad) / cell)) + 1)
    placed = EdgeFeatures(xy=(model_xy - origin) / cell, theta=model_theta)
    own = prepare_test(placed, shape, position_sigma=maps.position_sigma / cell,
                       orientation_kappa=ORIENTATION_KAPPA, edge_spacing=edge_spacing / cell)
    # A pooled model stacks several views' features on each contour: its
    # typical density on itself is what "explained" means.
    typical = float(np.median(density_at(own, placed.xy, placed.theta)))
    if not typical > 0:
        return 0.0
    values = density_at(own, (maps.xy[inside] - origin) / cell, maps.theta[inside])
    return float(np.mean(np.minimum(values / typical, 1.0)))


def rerank_by_coverage(probes: ProbeSet, model: PoseModel, maps: TestMaps | Sequence[TestMaps],
                       setup: SearchSetup) -> ProbeSet:
    """Multiply the best probes' scores by their coverage (:func:`coverage`).

    Parameters
    ----------
    probes : ProbeSet
        From :func:`posevote.inference.search.probe` on ``maps``.
    model : PoseModel
    maps : TestMaps or sequence of TestMaps
        The search's maps: one set, or one per scale (object units).
    setup : SearchSetup

    Returns
    -------
    ProbeSet
        The same probes with re-ranked scores.
    """
    score = probes.score
    best = np.argsort(-score.ravel(), kind="stable")[:COVERAGE_CANDIDATES]
    best = best[score.ravel()[best] > 0]
    if len(best) == 0:
        return probes
    per_scale = None if isinstance(maps, TestMaps) else list(maps)
    found = np.empty(len(best))
    views: dict[int, tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]] = {}
    for n, flat in enumerate(best):
        v, a, k = (int(i) for i in np.unravel_index(flat, score.shape))
        if v not in views:
            feats = viewpoint_features(model, probes.azimuth[v], probes.elevation[v],
                                       viewpoint_kappa=setup.viewpoint_kappa,
                                       use_weights=setup.use_weights, k1_cutoff=K1_CUTOFF)
            views[v] = (feats.xy, feats.theta, feats.box)
        xy, theta, box = views[v]
        # Per-scale maps hold the image divided by the scale: the model is at scale 1 there.
        s = float(probes.scale[k])
        if per_scale is None:
            test, size = maps, s
        else:
            test, size = per_scale[k], 1.0
        assert isinstance(test, TestMaps)
        centre = probes.translation[v, a, k] * (size / s)
        alpha = float(probes.inplane[a])
        placed = size * rotate_points(xy, alpha) + centre
        found[n] = coverage(placed, np.mod(theta + alpha, np.pi), test, size * box, centre,
                            edge_spacing=setup.edge_spacing * size)
    # Floored above 0 so that a probe explaining nothing keeps its rank among the rest.
    found = np.maximum(found, _FLOOR)
    factor = np.full(score.size, float(found.min()))
    factor[best] = found
    return replace(probes, score=np.where(score > 0, score * factor.reshape(score.shape), score))
