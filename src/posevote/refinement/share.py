"""The image-to-model direction: the share of the test edges a pose explains (beyond the paper).

The narrow score is the share of the model that the image explains. Alone
it favours a pose whose features can lie on other edges of the object: a
plainer side placed over a detailed one (:mod:`posevote.templates.halfturn`),
or the right view drawn in a little, its outline onto the edges just inside
the object's (more so in clutter, where the found viewpoint is a few degrees
off). The other direction, the share of the test edges near the object
that the pose's features explain (:func:`edge_share`), leans the other way:
a pose drawn in leaves the object's outline unexplained.
:func:`share_scale` takes the scale where the product of the two peaks
(with the ``cluttered`` preset; docs/history/DEFAULTS.md, "Scale from both
directions", has the measurements).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from posevote.geometry import rotate_points
from posevote.model.density import PoseModel
from posevote.model.kernels import K1_CUTOFF, ORIENTATION_KAPPA
from posevote.model.outline import box_outline, inside_outline, outline_at
from posevote.refinement.local import polish_pose
from posevote.results import Hypothesis
from posevote.scoring.maps import TestMaps
from posevote.scoring.score import (
    MIN_BOX_EDGES,
    ScoreSetup,
    ViewpointFeatures,
    explained_sums,
    gather_score,
    viewpoint_features,
)

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


def pose_features(hypothesis: Hypothesis, model: PoseModel, setup: ScoreSetup
                  ) -> ViewpointFeatures:
    """The training features of the pose's viewpoint, as the search weighs them."""
    return viewpoint_features(model, hypothesis.azimuth, hypothesis.elevation,
                              viewpoint_kappa=setup.viewpoint_kappa,
                              use_weights=setup.use_weights, k1_cutoff=K1_CUTOFF)


def inside_pose(hypothesis: Hypothesis, model: PoseModel, points: NDArray[np.float64],
                setup: ScoreSetup, features: ViewpointFeatures) -> NDArray[np.bool_]:
    """Which points lie inside the pose's outline (its views' box where the model has none)."""
    outline = outline_at(model, hypothesis.azimuth, hypothesis.elevation,
                         kappa=setup.viewpoint_kappa, k1_cutoff=K1_CUTOFF)
    if outline is None:
        outline = box_outline(features.box)
    return inside_outline(points, outline, hypothesis.position, hypothesis.scale,
                          hypothesis.inplane)


def edge_shares(hypothesis: Hypothesis, model: PoseModel, maps: TestMaps,
                selected: NDArray[np.bool_], setup: ScoreSetup, scales: ArrayLike, *,
                features: ViewpointFeatures | None = None) -> NDArray[np.float64]:
    """The share of the selected test edges that the pose's features explain, at each scale.

    As :func:`posevote.inference.coverage.coverage` reads it (the placed
    model's density at each test edge over its typical density on its own
    features, capped at 1, averaged), but summed exactly over the pairs of
    edges within :data:`_REACH_SIGMAS` kernel widths
    (:func:`posevote.scoring.score.explained_sums`) rather than read
    from a grid: the decisions that use it turn on a few percent.

    Parameters
    ----------
    hypothesis : Hypothesis
        In the frame of ``maps`` (image pixels); its scale is replaced by each of ``scales``.
    model : PoseModel
    maps : TestMaps
        The test edges (``xy``, ``theta``) and the narrow kernel's width.
    selected : ndarray of bool, shape (N,)
        The test edges counted.
    setup : ScoreSetup
    scales : array_like of float, shape (K,)
        Positive scales, about the pose's position.
    features : ViewpointFeatures, optional
        The pose's viewpoint features, if already collected.

    Returns
    -------
    ndarray, shape (K,)
        In [0, 1]; 0 with fewer than
        :data:`~posevote.scoring.score.MIN_BOX_EDGES` edges selected.
    """
    scales = np.asarray(scales, dtype=np.float64).reshape(-1)
    shares = np.zeros(len(scales))
    feats = pose_features(hypothesis, model, setup) if features is None else features
    if selected.sum() < MIN_BOX_EDGES or len(feats.xy) == 0 or len(scales) == 0:
        return shares
    sigma = float(maps.position_sigma)
    xy = rotate_points(feats.xy, hypothesis.inplane)
    theta = np.mod(feats.theta + hypothesis.inplane, np.pi)
    test_xy = maps.xy[selected] - np.asarray(hypothesis.position, dtype=np.float64)
    test_theta = maps.theta[selected]
    ones = np.ones(len(xy))
    # Its typical density on itself (a pooled model stacks several views on each
    # contour), read at evenly spaced features of its own.
    own = np.arange(0, len(xy), max(1, len(xy) // _TYPICAL_POINTS))
    for k, scale in enumerate(scales.tolist()):
        placed = scale * xy
        typical = float(np.median(explained_sums(placed, theta, ones, placed[own], theta[own],
                                                 sigma, ORIENTATION_KAPPA,
                                                 reach_sigmas=_REACH_SIGMAS)))
        if typical > 0:
            density = explained_sums(placed, theta, ones, test_xy, test_theta, sigma,
                                     ORIENTATION_KAPPA, reach_sigmas=_REACH_SIGMAS)
            shares[k] = float(np.mean(np.minimum(density / typical, 1.0)))
    return shares


def edge_share(hypothesis: Hypothesis, model: PoseModel, maps: TestMaps,
               selected: NDArray[np.bool_], setup: ScoreSetup, *,
               features: ViewpointFeatures | None = None) -> float:
    """The share of the selected test edges that the pose's features explain, at its scale.

    :func:`edge_shares` at the pose's own scale; the same parameters but ``scales``.

    Returns
    -------
    float
    """
    return float(edge_shares(hypothesis, model, maps, selected, setup, [hypothesis.scale],
                             features=features)[0])


def share_scale(hypothesis: Hypothesis, model: PoseModel, maps: TestMaps,
                setup: ScoreSetup) -> Hypothesis:
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
        The pose whose scale is set, in image pixels (after the half-turn check).
    model : PoseModel
    maps : TestMaps
        Narrow maps of the whole test image, in its pixels, as
        :func:`posevote.scoring.score.narrow_maps` makes them.
    setup : ScoreSetup

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
    scales = hypothesis.scale * np.exp(steps)
    value = np.array([gather_score(maps.density, maps.frame, feats.xy, feats.theta, feats.weight,
                                   hypothesis.inplane, scale, *hypothesis.position)
                      for scale in scales.tolist()], dtype=np.float64)
    value *= edge_shares(hypothesis, model, maps, selected, setup, scales, features=feats)
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
