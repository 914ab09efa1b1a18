"""The image-to-model direction: the share of the test edges a pose explains (beyond the paper).

The narrow score is the share of the model that the image explains. Alone
it favours a pose whose features can lie on other edges of the object: a
plainer side placed over a detailed one (:mod:`posevote.refinement.halfturn`),
or the right view drawn in a little, its outline onto the edges just inside
the object's (the rendered sphere's views on black: about 1% short at the
true viewpoint; in clutter, where the found viewpoint is a few degrees off,
about 2%). The other direction, the share of the test edges near the object
that the pose's features explain (:func:`edge_share`), leans the other way:
a pose drawn in leaves the object's outline unexplained.
:func:`share_scale` takes the scale where the product of the two peaks.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from posevote.geometry import rotate_points
from posevote.inference.coverage import MIN_BOX_EDGES
from posevote.inference.maps import TestMaps
from posevote.inference.search import SearchSetup, ViewpointFeatures, viewpoint_features
from posevote.inference.voting import gather_score
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

#: :func:`share_scale` tries the scales within this factor of the pose's,
#: in :data:`SHARE_SCALE_STEPS` even steps of its logarithm, and counts the
#: test edges inside the pose's outline grown by :data:`SHARE_SCALE_REACH`
#: (the object's own outline, where the pose falls short of it).
SHARE_SCALE_SPAN = 1.06
SHARE_SCALE_STEPS = 7
SHARE_SCALE_REACH = 1.06
#: Pairs of edges further apart than this many kernel widths add nothing.
_REACH_SIGMAS = 4.0
#: Model features at which its typical density on itself is read (evenly spaced).
_TYPICAL_POINTS = 256


def pose_features(hypothesis: Hypothesis, model: PoseModel, setup: SearchSetup
                  ) -> ViewpointFeatures:
    """The training features of the pose's viewpoint, as the search weighs them."""
    return viewpoint_features(model, hypothesis.azimuth, hypothesis.elevation,
                              viewpoint_kappa=setup.viewpoint_kappa,
                              use_weights=setup.use_weights, k1_cutoff=K1_CUTOFF)


def inside_pose(hypothesis: Hypothesis, model: PoseModel, points: NDArray[np.float64],
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
    from a grid: the decisions that use it turn on a few percent.

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
    feats = pose_features(hypothesis, model, setup) if features is None else features
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


def share_scale(hypothesis: Hypothesis, model: PoseModel, maps: TestMaps,
                setup: SearchSetup) -> Hypothesis:
    """The pose at the scale where its narrow score times its edge share peaks.

    The scales within :data:`SHARE_SCALE_SPAN` of the pose's are scored
    about its position (narrow score on ``maps`` times :func:`edge_share`
    of the test edges inside its outline grown by :data:`SHARE_SCALE_REACH`),
    the peak is read from a parabola through the best step and its
    neighbours, and the translation and in-plane angle are polished again at
    that scale.

    Parameters
    ----------
    hypothesis : Hypothesis
        The refined pose (image pixels).
    model : PoseModel
    maps : TestMaps
        The test image's narrow maps in image pixels
        (:func:`posevote.inference.search.image_maps`).
    setup : SearchSetup

    Returns
    -------
    Hypothesis
        The pose at its new scale, with its score as it came (the score that
        chose it); ``hypothesis`` itself where no scale explains any edge.
    """
    feats = pose_features(hypothesis, model, setup)
    if feats.weight.sum() <= 0:
        return hypothesis
    grown = replace(hypothesis, scale=hypothesis.scale * SHARE_SCALE_REACH)
    selected = inside_pose(grown, model, maps.xy, setup, feats)
    steps = np.linspace(-1.0, 1.0, SHARE_SCALE_STEPS) * np.log(SHARE_SCALE_SPAN)
    value = np.zeros(len(steps))
    for k, step in enumerate(steps):
        pose = replace(hypothesis, scale=hypothesis.scale * float(np.exp(step)))
        score = gather_score(maps.density, maps.frame, feats.xy, feats.theta, feats.weight,
                             pose.inplane, pose.scale, *pose.position)
        value[k] = float(score) * edge_share(pose, model, maps, selected, setup,
                                             features=feats)
    best = int(np.argmax(value))
    if not value[best] > 0:
        return hypothesis
    step = float(steps[best])
    if 0 < best < len(steps) - 1:
        below, peak, above = value[best - 1:best + 2]
        curve = below - 2.0 * peak + above
        if curve < 0:
            step += 0.5 * (below - above) / curve * float(steps[1] - steps[0])
    scale = hypothesis.scale * float(np.exp(step))
    polished = polish_pose(replace(hypothesis, scale=scale), model, maps,
                           viewpoint_kappa=setup.viewpoint_kappa, use_weights=setup.use_weights,
                           k1_cutoff=K1_CUTOFF, scale_bounds=(scale, scale))
    return replace(polished, score=hypothesis.score, refined=True)
