"""Local continuous maximisation of p(w) in (in-plane angle, scale, translation).

Beyond the paper: after the distribution fit has placed the viewpoint between
the training views, the exact likelihood p(w) (Eq. 3) of that viewpoint is
maximised over ``w2`` and ``w3`` with the narrow appearance kernel, starting
from the fit. The grid search had to widen its kernel to tolerate its own
step size; this step takes the estimate back to the resolution of the
features, which is what puts the object's position within a pixel or two.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numba
import numpy as np
from numpy.typing import NDArray

from posevote.features.edges import EdgeFeatures
from posevote.geometry import viewing_direction
from posevote.inference.probes import ProbeSet
from posevote.model.density import PoseModel
from posevote.refinement.fitting import (
    FIT_RADIUS_STEPS,
    VIEW_SHAPE,
    box_from_pose,
    neighbour_viewpoints,
    peak_viewpoint,
    refine_mode,
)
from posevote.results import Hypothesis
from posevote.scoring.maps import TestMaps, scaled_features
from posevote.scoring.score import (
    ScoreSetup,
    features_at,
    gather_score,
    gather_score_reference,
    median_spacing,
    narrow_maps,
    place_features,
    pose_score,
    score_options,
    shifted_score,
    viewpoint_features,
)

#: Weighs each pose's score: a factor per pose, positive (the templates' correlation, floored;
#: :func:`posevote.templates.match.correlation_weights`).
PoseWeights = Callable[[list[Hypothesis]], NDArray[np.float64]]

#: The polish moves the translation by at most this many pixels (each way).
POLISH_SHIFT = 8.0


def polish_pose(hypothesis: Hypothesis, model: PoseModel, maps: TestMaps, *,
                viewpoint_kappa: float, use_weights: bool = True, k1_cutoff: float = 0.1,
                max_shift: float = POLISH_SHIFT, scale_bounds: tuple[float, float] | None = None,
                max_features: int | None = None, turn: bool = True) -> Hypothesis:
    """Maximise the exact p(w) around a hypothesis over (alpha, log s, u, v).

    A compass search (:func:`_compass_search`, compiled): steps along each
    axis from about a pixel down to a twentieth of one.

    Parameters
    ----------
    hypothesis : Hypothesis
        Starting pose (its viewpoint is kept).
    model : PoseModel
        Training pairs.
    maps : TestMaps
        The test image, tabulated with the narrow kernel.
    viewpoint_kappa, use_weights, k1_cutoff
        As in :func:`posevote.scoring.score.viewpoint_features`.
    max_shift : float, optional
        The translation moves at most this many pixels; the angle and scale
        at most by the equivalent at the model's typical radius.
    scale_bounds : (float, float) or None, optional
        The scale also stays within these bounds (or, if the hypothesis
        starts outside them, no farther out than it starts).
    max_features : int or None, optional
        Polish on at most about this many of the view's features (an even
        stride, :func:`posevote.scoring.score.subsample_features`); the
        returned score is then theirs.
    turn : bool, optional
        False holds the in-plane angle (scale and translation only).

    Returns
    -------
    Hypothesis
        The polished pose (or the input pose if nothing better was found),
        with its exact narrow-kernel score.
    """
    feats = features_at(hypothesis, model, viewpoint_kappa=viewpoint_kappa,
                           use_weights=use_weights, k1_cutoff=k1_cutoff,
                           max_features=max_features)
    if feats.weight.sum() <= 0:
        return hypothesis
    radius = max(float(np.sqrt(np.mean(np.sum(feats.xy**2, axis=1)))) * hypothesis.scale, 1.0)
    # Work in units where one step moves a typical feature by about a pixel.
    unit = np.array([1.0 / radius if turn else 0.0, 1.0 / radius, 1.0, 1.0])
    start = np.array([hypothesis.inplane, np.log(hypothesis.scale), *hypothesis.position])
    log_lo, log_hi = (-np.inf, np.inf) if scale_bounds is None else np.log(scale_bounds)
    log_lo, log_hi = min(log_lo, start[1]), max(log_hi, start[1])

    bounds = np.array([log_lo, log_hi])
    z, best, initial = _compass_search(maps.density, maps.frame, feats.xy, feats.theta,
                                       feats.weight, start, unit, bounds, max_shift)
    if not best > initial:
        return replace(hypothesis, score=float(initial))
    alpha, log_s, u, v = start + z * unit
    scale = float(np.exp(log_s))
    return replace(hypothesis, inplane=float(alpha), scale=scale, position=(float(u), float(v)),
                   box=box_from_pose(np.array([u, v]), feats.box * scale, float(alpha)),
                   score=float(best))


#: The compass search starts with steps of this many units (about a pixel at
#: the model's typical radius) and stops below ``_COMPASS_LAST``; at most
#: ``_COMPASS_EVALS`` evaluations.
_COMPASS_FIRST = 1.5
_COMPASS_LAST = 0.05
_COMPASS_EVALS = 400


@numba.njit(cache=True, nogil=True)
def _compass_search(density, frame, xy, theta, weight, start, unit, log_bounds, max_shift
                    ):  # pragma: no cover - compiled
    """Maximise p(w) over ``start + z * unit`` by a compass search in z (|z| <= max_shift).

    From z = 0, each round tries a step of the current length along each of
    the four axes, both ways, and moves to the best that improves; without
    one, the step is halved. Returns (z, its score, the score at z = 0).
    """
    z = np.zeros(4)
    best = gather_score(density, frame, xy, theta, weight, start[0], np.exp(start[1]), start[2],
                        start[3])
    initial = best
    step = _COMPASS_FIRST
    evals = 1
    trial = np.empty(4)
    # The features turned at the current angle and scale: the shifts' trials
    # (half of them) then skip the turn and the orientation bins.
    n = xy.shape[0]
    px, py, ft = np.empty(n), np.empty(n), np.empty(n)
    bins = np.empty((n, 2), dtype=np.int64)
    n_bins = density.shape[0]
    place_features(frame, n_bins, xy, theta, start[0] + z[0] * unit[0],
                   np.exp(start[1] + z[1] * unit[1]), 0.0, 0.0, px, py, bins, ft)
    while step >= _COMPASS_LAST and evals < _COMPASS_EVALS:
        move = -1
        move_value = best
        for k in range(8):
            # A unit of 0 holds that axis (rescale_mode keeps the fitted in-plane angle).
            if unit[k // 2] == 0.0:
                continue
            trial[:] = z
            trial[k // 2] += step if k % 2 == 0 else -step
            if abs(trial[k // 2]) > max_shift:
                continue
            log_s = start[1] + trial[1] * unit[1]
            if log_s < log_bounds[0] or log_s > log_bounds[1]:
                continue
            if k >= 4:
                value = shifted_score(density, frame, weight, px, py, bins, ft,
                                      start[2] + trial[2] * unit[2],
                                      start[3] + trial[3] * unit[3], 1)
            else:
                value = gather_score(density, frame, xy, theta, weight,
                                     start[0] + trial[0] * unit[0],
                                     np.exp(log_s), start[2] + trial[2] * unit[2],
                                     start[3] + trial[3] * unit[3])
            evals += 1
            if value > move_value:
                move = k
                move_value = value
        if move < 0:
            step *= 0.5
        else:
            z[move // 2] += step if move % 2 == 0 else -step
            best = move_value
            if move < 4:
                place_features(frame, n_bins, xy, theta, start[0] + z[0] * unit[0],
                               np.exp(start[1] + z[1] * unit[1]), 0.0, 0.0, px, py, bins, ft)
    return z, best, initial


def compass_search_reference(maps: TestMaps, xy: NDArray[np.float64],
                             theta: NDArray[np.float64], weight: NDArray[np.float64],
                             start: NDArray[np.float64], unit: NDArray[np.float64],
                             log_bounds: NDArray[np.float64], max_shift: float
                             ) -> tuple[NDArray[np.float64], float, float]:
    """:func:`_compass_search` in numpy (for tests)."""
    def score(z: NDArray[np.float64]) -> float:
        alpha, log_s, u, v = start + z * unit
        return gather_score_reference(maps, xy, theta, weight, alpha, float(np.exp(log_s)), u, v)

    z, step, evals = np.zeros(4), _COMPASS_FIRST, 1
    best = initial = score(z)
    while step >= _COMPASS_LAST and evals < _COMPASS_EVALS:
        trials = []
        for k in range(8):
            if unit[k // 2] == 0.0:
                continue
            trial = z.copy()
            trial[k // 2] += step if k % 2 == 0 else -step
            log_s = start[1] + trial[1] * unit[1]
            if abs(trial[k // 2]) <= max_shift and log_bounds[0] <= log_s <= log_bounds[1]:
                trials.append((score(trial), k, trial))
                evals += 1
        improving = [t for t in trials if t[0] > best]
        if not improving:
            step *= 0.5
            continue
        best, _, z = max(improving, key=lambda t: (t[0], -t[1]))
    return z, best, initial


def probe_pose(probes: ProbeSet, viewpoint: int, inplane: int, scale: int) -> Hypothesis:
    """The pose of one probe of the grid, with its score (unrefined)."""
    position = probes.translation[viewpoint, inplane, scale]
    alpha, factor = float(probes.inplane[inplane]), float(probes.scale[scale])
    return Hypothesis(azimuth=float(probes.azimuth[viewpoint]),
                      elevation=float(probes.elevation[viewpoint]), inplane=alpha, scale=factor,
                      position=(float(position[0]), float(position[1])),
                      box=box_from_pose(position, probes.box[viewpoint] * factor, alpha),
                      score=float(probes.score[viewpoint, inplane, scale]), refined=False)


def at_viewpoint(probes: ProbeSet, viewpoint: int, pose: Hypothesis) -> Hypothesis:
    """``pose``'s in-plane angle, scale and position at one of the probed viewpoints."""
    return replace(pose, azimuth=float(probes.azimuth[viewpoint]),
                   elevation=float(probes.elevation[viewpoint]), refined=False,
                   box=box_from_pose(np.asarray(pose.position), probes.box[viewpoint] * pose.scale,
                                     pose.inplane))


def in_frame(pose: Hypothesis, factor: float) -> Hypothesis:
    """``pose`` in an image whose coordinates are divided by ``factor`` (scale too)."""
    x, y, w, h = pose.box
    return replace(pose, scale=pose.scale / factor,
                   position=(pose.position[0] / factor, pose.position[1] / factor),
                   box=(x / factor, y / factor, w / factor, h / factor))


def rescale_anchor(probes: ProbeSet, viewpoint: int, model: PoseModel,
                   features: EdgeFeatures, shape: tuple[int, int], setup: ScoreSetup, *,
                   weigh: PoseWeights | None = None) -> tuple[Hypothesis, int] | None:
    """Choose a mode's scale again with the narrow kernel in object units (beyond the paper).

    At each scale of the grid, the viewpoint's best probe is polished
    (:func:`polish_pose`, within half a grid step) on the test image divided
    by that scale and tabulated with the narrow kernel, and scored above
    that image's chance level. The search's wide kernel blurs the object's
    inner detail, and under occlusion a smaller model fitted to the visible
    part then scores as well as the right one; the narrow kernel in object
    units tells them apart without favouring small scales (a kernel fixed
    in pixels is relatively wider on a small model). Each scale's maps are
    tabulated only where its polish can read them (the probe's reach), with
    the whole image's values and chance level.

    Parameters
    ----------
    probes : ProbeSet
        The probes of the grid search.
    viewpoint : int
        The mode's best viewpoint.
    model : PoseModel
        Training pairs.
    features : EdgeFeatures
        The test features, image pixels.
    shape : (int, int)
        The image's shape.
    setup : ScoreSetup
        The search's setup (narrow kernel, pose kernel, weights).
    weigh : callable, optional
        Each polished pose's weight by its grey levels (:data:`PoseWeights`);
        with it a scale's chance-corrected score is multiplied by it, as the
        search's were, so that another scale's best probe on the clutter
        does not win on edges alone.

    Returns
    -------
    (Hypothesis, int) or None
        The polished pose in image coordinates and the index of its scale;
        None if no scale has a probe with a positive score.
    """
    kw = score_options(setup)
    half = 0.5 * float(np.median(np.diff(np.log(probes.scale)))) if len(probes.scale) > 1 else 0.05
    feats = viewpoint_features(model, float(probes.azimuth[viewpoint]),
                               float(probes.elevation[viewpoint]), **kw)
    # How far from its start the polish can read: its shift, the features'
    # reach at the largest scale it may take, and the bilinear read's pixel.
    reach = POLISH_SHIFT + float(np.exp(half)) * float(
        np.sqrt(np.max(np.sum(feats.xy**2, axis=1), initial=0.0))) + 2.0
    found: list[tuple[float, Hypothesis, int]] = []
    for s, factor in enumerate(probes.scale.tolist()):
        a = int(np.argmax(probes.score[viewpoint, :, s]))
        if probes.score[viewpoint, a, s] <= 0:
            continue
        probe = probe_pose(probes, viewpoint, a, s)
        start = in_frame(probe, factor)
        maps = maps_around(features, shape, setup, factor, start.position, reach)
        polished = polish_pose(start, model, maps, **kw,
                               scale_bounds=(float(np.exp(-half)), float(np.exp(half))))
        found.append((above_chance(polished.score, maps),
                      replace(in_frame(polished, 1.0 / factor), score=probe.score), s))
    if not found:
        return None
    value = np.array([f[0] for f in found])
    if weigh is not None:
        factor = weigh([f[1] for f in found])
        value = np.where(value > 0, value * factor, value)
    best = found[int(np.argmax(value))]
    return best[1], best[2]


def above_chance(score: float, maps: TestMaps) -> float:
    """A narrow score as the share of the way from the maps' chance level to 1."""
    chance = min(maps.chance, 0.99)
    return (score - chance) / (1.0 - chance)


def unit_score(hypothesis: Hypothesis, model: PoseModel, features: EdgeFeatures,
               shape: tuple[int, int], setup: ScoreSetup) -> float:
    """A pose's narrow score above chance, the kernel in object units at its own scale.

    As :func:`rescale_anchor` scores each scale, for a pose as it stands (no
    polish): poses of different scales then compare without the small one's
    advantage of a kernel relatively wider and more clutter per feature.

    Parameters
    ----------
    hypothesis : Hypothesis
        The pose (image pixels).
    model : PoseModel
    features : EdgeFeatures
        The test features, image pixels.
    shape : (int, int)
        The image's shape.
    setup : ScoreSetup

    Returns
    -------
    float
        At most 1; below 0 where the pose explains less than chance does.
    """
    kw = score_options(setup)
    factor = hypothesis.scale
    feats = viewpoint_features(model, hypothesis.azimuth, hypothesis.elevation, **kw)
    # The maps are tabulated only where the pose's features land (and the read's pixel).
    reach = float(np.sqrt(np.max(np.sum(feats.xy**2, axis=1), initial=0.0))) + 2.0
    pose = in_frame(hypothesis, factor)
    maps = maps_around(features, shape, setup, factor, pose.position, reach)
    return above_chance(pose_score(pose, model, maps, **kw), maps)


def maps_around(features: EdgeFeatures, shape: tuple[int, int], setup: ScoreSetup,
                factor: float, position: tuple[float, float], reach: float) -> TestMaps:
    """Narrow maps of the test image divided by ``factor`` (object units at that scale),
    tabulated within ``reach`` of ``position`` (in that frame), with the whole image's
    values and chance level."""
    scaled, (h, w) = scaled_features(features, shape, factor)
    # Clamped to meet the image: a pose that reads only past it scores 0 either way.
    u, v = np.clip(position, 0.0, (w - 1, h - 1))
    region = (int(np.floor(u - reach)), int(np.floor(v - reach)),
              int(np.ceil(u + reach)), int(np.ceil(v + reach)))
    return narrow_maps(scaled, (h, w), setup, scale=factor, region=region)


def start_near(probes: ProbeSet, viewpoint: int, anchor: Hypothesis) -> Hypothesis:
    """The best probe of a viewpoint that lies on the same object as an anchor pose.

    Parameters
    ----------
    probes : ProbeSet
        The probes of the grid search.
    viewpoint : int
        Index of the viewpoint.
    anchor : Hypothesis
        The mode's pose; its position is where the object was found.

    Returns
    -------
    Hypothesis
        The best of the viewpoint's probes whose box (at its in-plane angle
        and scale) contains the anchor's position; in clutter a neighbouring
        viewpoint's best probe may sit on another part of the image. If none
        does, the anchor's in-plane angle, scale and position at this
        viewpoint.
    """
    offset = np.abs(probes.translation[viewpoint] - np.asarray(anchor.position))  # (A, S, 2)
    cos, sin = np.abs(np.cos(probes.inplane)), np.abs(np.sin(probes.inplane))
    w, h = probes.box[viewpoint]
    half = np.stack([w * cos + h * sin, w * sin + h * cos], axis=-1)[:, None, :] \
        * probes.scale[None, :, None] / 2.0
    inside = np.all(offset <= half, axis=-1)
    score = np.where(inside, probes.score[viewpoint], -np.inf)
    if not np.isfinite(score).any():
        return at_viewpoint(probes, viewpoint, anchor)
    a, s = np.unravel_index(int(np.argmax(score)), score.shape)
    return probe_pose(probes, viewpoint, int(a), int(s))


def viewpoint_profile(azimuth: NDArray[np.float64], elevation: NDArray[np.float64],
                      score: NDArray[np.float64], box: NDArray[np.float64]) -> ProbeSet:
    """Maximised scores by viewpoint as probes of one in-plane angle and scale (for the fits)."""
    return ProbeSet(azimuth=azimuth, elevation=elevation, inplane=np.zeros(1), scale=np.ones(1),
                    score=score[:, None, None], translation=np.zeros((len(score), 1, 1, 2)),
                    box=box)


def profile_refine(probes: ProbeSet, viewpoint: int, model: PoseModel, maps: TestMaps, *,
                   viewpoint_kappa: float, use_weights: bool = True, k1_cutoff: float = 0.1,
                   radius_steps: float = 2.5, scale_margin: float | None = None,
                   view_shape: float = VIEW_SHAPE, anchor: Hypothesis | None = None,
                   frame_scale: float = 1.0,
                   weigh: PoseWeights | None = None) -> Hypothesis:
    """Fit the viewpoint on the profile likelihood, then polish (beyond the paper).

    For every probed viewpoint near the mode, the exact p(w) is maximised over
    in-plane angle, scale and translation with the narrow kernel
    (:func:`polish_pose`, started from that viewpoint's best probe on the
    mode's object, :func:`start_near`). The viewpoint distribution of
    Sec. II-B is then fitted to these maximised scores instead of the
    grid's (on a turntable; over the sphere the peak of a quadratic through
    the best view and its nearest neighbours, :func:`peak_viewpoint`), and
    the pose is polished once more at that viewpoint. The grid's coarse
    steps and widened kernel then no longer blur the comparison between
    viewpoints.

    Parameters
    ----------
    probes : ProbeSet
        The probes of the grid search.
    viewpoint : int
        The mode's best viewpoint.
    model, maps, viewpoint_kappa, use_weights, k1_cutoff
        As in :func:`polish_pose` (``maps`` with the narrow kernel).
    radius_steps : float, optional
        Viewpoints within this many probe spacings take part.
    view_shape : float, optional
        Exponent of the fitted viewpoint term (:func:`refine_mode`, turntables).
    scale_margin : float or None, optional
        Every polish keeps the scale within a factor ``exp(scale_margin)``
        of the mode's best probe (None: only the polish's own step bound).
        The narrow score is not corrected for chance, and in clutter it
        grows as the model shrinks onto dense edges; the search, whose
        score is, chose the scale.
    anchor : Hypothesis, optional
        The mode's pose (for instance from :func:`rescale_anchor`): the
        mode's viewpoint starts there, and the other viewpoints' starts
        (:func:`start_near`) have their scale brought into the band around
        it. By default the viewpoint's best probe.
    frame_scale : float, optional
        ``maps`` tabulate the test image divided by this factor (the kernel
        in object units at that scale); poses are converted in and out.
    weigh : callable, optional
        Each polished pose's weight by its grey levels (:data:`PoseWeights`);
        with it every viewpoint's maximised score is multiplied by it before
        the fit, as the search's probes and :func:`rescale_anchor`'s scales
        are: in clutter the edges alone let a neighbouring view's polish
        score on the background. The pose returned is scored the same way.

    Returns
    -------
    Hypothesis
    """
    views = neighbour_viewpoints(probes, viewpoint, radius_steps=radius_steps)
    given = anchor is not None
    if anchor is None:
        anchor = refine_mode(probes, viewpoint, fit=False)
    centre = anchor.scale / frame_scale
    bounds = None if scale_margin is None else (centre * float(np.exp(-scale_margin)),
                                                centre * float(np.exp(scale_margin)))
    polished = []
    for v in views:
        start = anchor if given and v == viewpoint else start_near(probes, int(v), anchor)
        if given and bounds is not None:
            start = replace(start, scale=float(np.clip(start.scale, *(frame_scale * np.array(bounds)))))
        polished.append(polish_pose(in_frame(start, frame_scale), model, maps,
                                    viewpoint_kappa=viewpoint_kappa, use_weights=use_weights,
                                    k1_cutoff=k1_cutoff, scale_bounds=bounds))
    score = np.array([h.score for h in polished])
    if weigh is not None:
        score = score * weigh([in_frame(h, 1.0 / frame_scale) for h in polished])
    profile = viewpoint_profile(probes.azimuth[views], probes.elevation[views], score,
                                probes.box[views])
    best = int(np.argmax(score))
    seed = polished[best]
    if profile.turntable:
        fitted = refine_mode(profile, best, radius_steps=radius_steps, view_shape=view_shape)
        peak = (fitted.azimuth, fitted.elevation) if fitted.refined else None
    else:
        # Over the sphere the views ring the best one unevenly: the peak is read
        # from its nearest neighbours alone.
        peak = peak_viewpoint(profile, best)
    if peak is None:
        return replace(in_frame(seed, 1.0 / frame_scale), score=float(score[best]))
    moved = replace(seed, azimuth=peak[0], elevation=peak[1], refined=True)
    final = in_frame(polish_pose(moved, model, maps, viewpoint_kappa=viewpoint_kappa,
                                 use_weights=use_weights, k1_cutoff=k1_cutoff,
                                 scale_bounds=bounds), 1.0 / frame_scale)
    if weigh is not None:
        # Scored as the profile's poses were, so that modes and images compare.
        final = replace(final, score=final.score * float(weigh([final])[0]))
    return replace(final, refined=True)


def refine_viewpoint(hypothesis: Hypothesis, model: PoseModel, maps: TestMaps,
                     setup: ScoreSetup, weigh: PoseWeights, *,
                     scale_bounds: tuple[float, float] | None = None) -> Hypothesis:
    """A pose's viewpoint read from the training views around it, as :func:`profile_refine`
    reads the found pose's over the sphere (beyond the paper).

    The pose is polished (:func:`polish_pose`) at every training viewpoint
    within :data:`~posevote.refinement.fitting.FIT_RADIUS_STEPS` spacings of
    its own, each polish scored by its narrow score times its weight; the
    viewpoint is read at the peak of that profile
    (:func:`~posevote.refinement.fitting.peak_viewpoint`) and the pose polished
    there. The half-turn check reads both its sides so, that the two poses
    it compares are refined alike. Models of one elevation return the pose
    as it is (their profile is fitted on the search's finer grid, which only
    :func:`profile_refine` has).

    Parameters
    ----------
    hypothesis : Hypothesis
        The pose (image pixels).
    model : PoseModel
    maps : TestMaps
        The image's narrow maps in pixels.
    setup : ScoreSetup
    weigh : callable
        Each pose's weight by its grey levels (:data:`PoseWeights`).
    scale_bounds : (float, float), optional
        Every polish keeps the scale within these (:func:`polish_pose`): a pose a few
        pixels across moves its scale far in one polish, and the narrow score grows as
        a model shrinks onto dense edges.

    Returns
    -------
    Hypothesis
        The polished pose at the profile's peak, or at its best training
        viewpoint where the profile has no peak; scored as :func:`polish_pose`
        scores.
    """
    if not np.ptp(model.view_elevation) > 0:
        return hypothesis
    kw = score_options(setup)
    directions = viewing_direction(model.view_azimuth, model.view_elevation)
    near = np.flatnonzero(directions @ viewing_direction(hypothesis.azimuth, hypothesis.elevation)
                          >= np.cos(FIT_RADIUS_STEPS * median_spacing(directions)))
    if len(near) < 5:
        return hypothesis
    kw = {**kw, "scale_bounds": scale_bounds}
    polished = [polish_pose(replace(hypothesis, azimuth=float(model.view_azimuth[i]),
                                    elevation=float(model.view_elevation[i])), model, maps, **kw)
                for i in near]
    score = np.array([h.score for h in polished]) * weigh(polished)
    profile = viewpoint_profile(model.view_azimuth[near], model.view_elevation[near], score,
                                model.view_box[near])
    best = int(np.argmax(score))
    peak = peak_viewpoint(profile, best)
    if peak is None:
        return polished[best]
    return polish_pose(replace(polished[best], azimuth=peak[0], elevation=peak[1]), model, maps,
                       **kw)


#: The local refinement keeps the scale within this many steps of the search's
#: scale grid (at least 5% a step) of the mode's best probe: its narrow score
#: is not corrected for chance, and in clutter it grows as the model shrinks
#: onto dense edges (chosen on the clutter self-test, docs/DEFAULTS.md).
REFINE_SCALE_STEPS = 1.0


def local_refine(probes: ProbeSet, viewpoint: int, hypothesis: Hypothesis, model: PoseModel,
                 setup: ScoreSetup, *, profile: bool, narrow: Callable[[], TestMaps],
                 scale_step: float, object_units: bool = False,
                 features: EdgeFeatures | None = None, shape: tuple[int, int] | None = None,
                 weigh: PoseWeights | None = None) -> Hypothesis:
    """The local refinement of one mode (beyond the paper).

    With ``profile``, the profile likelihood around the mode's best
    viewpoint is fitted (:func:`profile_refine`); with ``object_units`` the
    mode's scale is first chosen again among the search's scales on narrow
    maps in object units (:func:`rescale_anchor`), and the profile is fitted
    on that scale's: the search's wide kernel blurs the object's inner
    detail, so that under occlusion a model shrunk onto the visible part
    scores as well as the right one. Without ``profile`` the mode's pose is
    only polished (:func:`polish_pose`).

    Parameters
    ----------
    probes : ProbeSet
        The search's probes.
    viewpoint : int
        The mode's best viewpoint.
    hypothesis : Hypothesis
        The mode's pose (fitted or not).
    model : PoseModel
    setup : ScoreSetup
    profile : bool
        Fit the viewpoint (else polish only).
    narrow : callable
        Returns the test image's narrow maps in pixels
        (:func:`posevote.scoring.score.narrow_maps`), called only when they
        are read.
    scale_step : float
        The search grid's log-scale step: the scale stays within
        :data:`REFINE_SCALE_STEPS` of them (at least 5% a step).
    object_units : bool, optional
        With ``profile``, choose the scale again in object units (the search's
        kernel was in object units).
    features : EdgeFeatures, optional
        The test features, image pixels (with ``object_units``).
    shape : (int, int), optional
        The image's shape, with ``features``.
    weigh : callable, optional
        Weighs by the grey levels that choice (:func:`rescale_anchor`) and
        the viewpoints' profile (:func:`profile_refine`).

    Returns
    -------
    Hypothesis

    Raises
    ------
    ValueError
        With ``object_units`` but no features and shape.
    """
    kw = score_options(setup)
    if not profile:
        return polish_pose(hypothesis, model, narrow(), **kw)
    margin = REFINE_SCALE_STEPS * max(scale_step, 0.05)
    if object_units:
        if features is None or shape is None:
            raise ValueError("local_refine in object units needs the features and shape")
        if chosen := rescale_anchor(probes, viewpoint, model, features, shape, setup,
                                    weigh=weigh):
            anchor, s = chosen
            factor = float(probes.scale[s])
            scaled = narrow_maps(*scaled_features(features, shape, factor), setup, scale=factor)
            return profile_refine(probes, viewpoint, model, scaled, scale_margin=margin,
                                  radius_steps=FIT_RADIUS_STEPS, anchor=anchor,
                                  frame_scale=factor, weigh=weigh, **kw)
    return profile_refine(probes, viewpoint, model, narrow(), scale_margin=margin,
                          radius_steps=FIT_RADIUS_STEPS, weigh=weigh, **kw)


def rescale_mode(hypothesis: Hypothesis, model: PoseModel, maps: TestMaps,
                 setup: ScoreSetup) -> Hypothesis:
    """The fitted mode's scale and position polished on the narrow maps, its angles and
    score kept.

    The fit reads the scale from the search's wide-kernel scores, whose fall-off
    is slower toward small scales, so it reads a few percent short; the narrow
    kernel's peak does not (docs/history/METHOD-NOTES.md). The score stays the fit's, on
    which ``min_score`` and the modes' probabilities are calibrated.

    Parameters
    ----------
    hypothesis : Hypothesis
        The fitted mode.
    model : PoseModel
        A one-instance model (a category's pooled views pull the narrow
        kernel onto one instance's inner edges).
    maps : TestMaps
        The test image with the narrow kernel, pixels.
    setup : ScoreSetup
        The search's setup (pose kernel, weights).

    Returns
    -------
    Hypothesis
        ``hypothesis`` with the polished scale, position and box.
    """
    polished = polish_pose(hypothesis, model, maps, turn=False, **score_options(setup))
    return replace(hypothesis, scale=polished.scale, position=polished.position,
                   box=polished.box)
