"""The search (Fig. 2): probes of p(w) over viewpoint x in-plane angle x scale.

For each discrete viewpoint ``w1`` the training features of nearby training
views (pose kernel K1) are collected with vote weights ``wt_i * K1``; for
each in-plane/scale step ``w2`` the translation ``w3`` is found by voting
(:mod:`posevote.inference.voting`). The result is a
:class:`~posevote.inference.probes.ProbeSet`: the set of (pose, score) pairs
approximating p(w) at discrete probes. :func:`probe` runs the search on the
grid of a :class:`~posevote.inference.setup.SearchSetup`, in one of the
strategies :func:`search_strategy` names.
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from posevote.geometry import viewing_direction
from posevote.inference.probes import ProbeSet, probe_spacing
from posevote.inference.setup import SearchOptions, SearchSetup
from posevote.inference.voting import (
    polish_translations,
    search_translations,
    strongest_voters,
)
from posevote.model.density import PoseModel
from posevote.model.kernels import K1_CUTOFF
from posevote.results import Hypothesis
from posevote.scoring.maps import TestMaps
from posevote.scoring.score import median_spacing, subsample_features, viewpoint_features

#: Training features that vote per probe (the heaviest; all count in the
#: exact score): the vote only has to find the peak's neighbourhood.
MAX_VOTERS = 100
#: Vote peaks per probe whose exact score is computed; the best is polished.
VOTE_CANDIDATES = 2
#: The most probes (viewpoints x in-plane angles x scales) one search may
#: hold, and the most in-plane angles or scales: a grid past these is refused
#: before anything is allocated.
MAX_PROBES = 2_000_000
#: A search near a known pose (:func:`probe` with ``near``) probes, with
#: per-scale maps, the scales within this many grid steps of its scale:
#: chosen on the five epfl-cv folds (better or equal on each than all six
#: scales; docs/DEFAULTS.md).
NEAR_SCALE_STEPS = 1.5
#: A ranking search (unpolished, per-scale maps) probes every other scale at
#: every viewpoint, and the scales between at this share of the viewpoints,
#: those that score best on the first: chosen on the five epfl-cv folds (the
#: same share under 45 degrees on each fold as all scales everywhere).
RANKING_VIEWPOINTS = 1.0 / 3.0
#: On the viewing sphere (viewpoints at several elevations) the ranking search
#: probes the every-other scales first at a subset of viewpoints this many grid
#: spacings apart, then at every viewpoint within that reach of the best
#: RANKING_VIEWPOINTS of them: by hand, measured on the rendered sphere's
#: development seeds (docs/DEFAULTS.md, named constants).
COARSE_STEPS = 2.0
#: A polished search over one set of maps (the default preset's) probes every
#: viewpoint unpolished, then polishes the viewpoints the continuous fit of the
#: POLISHED_MODES best will read: those within POLISH_REACH_STEPS probe
#: spacings of them (the fit's reach, ``refinement.fitting.FIT_RADIUS_STEPS``).
POLISHED_MODES = 3
POLISH_REACH_STEPS = 2.5


def viewpoint_grid(model: PoseModel, *, subdivisions: int = 1, step: float | None = None
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Viewpoints to probe: the training viewpoints, optionally subdivided.

    Because K1 blends neighbouring training views, psi is defined between
    them and may be probed on a finer grid. For turntable models (one
    elevation) ``subdivisions - 1`` azimuths are inserted between each pair of
    neighbouring training azimuths; otherwise the training viewpoints are
    used as they are. With ``step`` (radians), turntable models are probed
    on a regular azimuth grid of that spacing instead, whatever the
    training views: dense, irregular training sets (a car sequence with a
    view every 3 degrees, several cars pooled) then cost a fixed number of
    probes.

    Returns
    -------
    azimuth, elevation : ndarray
        Radians, sorted by azimuth for turntable models.
    """
    if subdivisions < 1:
        raise ValueError(f"subdivisions must be >= 1, got {subdivisions}")
    az, el = model.viewpoints[:, 0].copy(), model.viewpoints[:, 1].copy()
    if step is not None and np.ptp(el) <= 1e-9:
        if not step > 0:
            raise ValueError(f"step must be positive, got {step}")
        n = max(int(round(2 * np.pi / step)), 1)
        regular = np.arange(n, dtype=np.float64) * (2 * np.pi / n)
        return regular, np.full(n, float(el[0]))
    if np.ptp(el) > 1e-9 or subdivisions == 1 or len(az) < 2:
        return np.asarray(az, dtype=np.float64), np.asarray(el, dtype=np.float64)
    az = np.sort(az)
    gaps = np.diff(np.append(az, az[0] + 2 * np.pi))
    steps = np.arange(subdivisions) / subdivisions
    fine = np.mod((az[:, None] + gaps[:, None] * steps[None, :]).ravel(), 2 * np.pi)
    return fine, np.full_like(fine, el[0])


# A model's search features by viewpoint: the grid's viewpoints recur in every
# image, and collecting them is a good part of a viewpoint's searches.
_PROBE_CACHE: weakref.WeakKeyDictionary[PoseModel, dict[tuple[Any, ...], tuple[
    NDArray[Any], ...]]] = weakref.WeakKeyDictionary()
_PROBE_CACHE_SIZE = 4096
_PROBE_LOCK = threading.Lock()


def _probe_features(model: PoseModel, azimuth: float, elevation: float, *,
                    viewpoint_kappa: float, use_weights: bool, k1_cutoff: float,
                    max_features: int | None, max_voters: int | None
                    ) -> tuple[NDArray[Any], ...]:
    """:func:`viewpoint_features` subsampled for the search: (xy, theta, weight, box, voters).

    Kept per model (at most ``_PROBE_CACHE_SIZE`` viewpoints); the arrays are
    shared between searches and must not be modified.
    """
    key = (azimuth, elevation, float(viewpoint_kappa), bool(use_weights), float(k1_cutoff),
           max_features, max_voters)
    with _PROBE_LOCK:
        cache = _PROBE_CACHE.setdefault(model, {})
        found = cache.get(key)
    if found is not None:
        return found
    feats = viewpoint_features(model, azimuth, elevation, viewpoint_kappa=viewpoint_kappa,
                               use_weights=use_weights, k1_cutoff=k1_cutoff)
    # Subsampled once for all the viewpoint's scales.
    xy, theta, weight = subsample_features(feats.xy, feats.theta, feats.weight, max_features)
    made = (xy, theta, weight, feats.box, strongest_voters(weight, max_voters))
    with _PROBE_LOCK:
        if len(cache) >= _PROBE_CACHE_SIZE:
            cache.clear()
        cache[key] = made
    return made


def _search_features(model: PoseModel, azimuth: float, elevation: float,
                     kw: dict[str, Any]) -> tuple[NDArray[Any], ...]:
    """:func:`_probe_features` with the settings of a search's keywords (``probe``'s ``kw``)."""
    return _probe_features(model, azimuth, elevation, viewpoint_kappa=kw["viewpoint_kappa"],
                           use_weights=kw["use_weights"], k1_cutoff=kw["k1_cutoff"],
                           max_features=kw["max_features"], max_voters=kw["max_voters"])


def probe_poses(
    model: PoseModel,
    maps: TestMaps | Sequence[TestMaps],
    *,
    azimuths: NDArray[np.float64],
    elevations: NDArray[np.float64],
    inplanes: NDArray[np.float64],
    scales: NDArray[np.float64],
    viewpoint_kappa: float,
    use_weights: bool = True,
    k1_cutoff: float = 0.1,
    cell: float | None = None,
    n_candidates: int = 3,
    max_voters: int | None = 200,
    max_features: int | None = None,
    progress: Callable[[int], None] | None = None,
    n_threads: int = 1,
    polish: bool = True,
) -> ProbeSet:
    """Evaluate p(w) at every probe of the grid (Fig. 2).

    Parameters
    ----------
    model : PoseModel
        Training pairs.
    maps : TestMaps or sequence of TestMaps
        The prepared test image: one set of maps for every scale (position
        kernel fixed in image pixels, the paper's K2), or one per scale,
        each prepared from the test features divided by that scale
        (position kernel fixed in object units; see
        :func:`posevote.scoring.maps.scaled_features`).
    azimuths, elevations : ndarray, shape (V,)
        Viewpoints to probe, radians.
    inplanes : ndarray, shape (A,)
        In-plane angles, radians.
    scales : ndarray, shape (S,)
        Scales relative to the training images.
    viewpoint_kappa : float
        Concentration of the pose kernel K1.
    use_weights : bool, optional
        Use the features' weights (Eq. 4); all ones otherwise.
    k1_cutoff : float, optional
        Training views whose K1 is below this are left out of a viewpoint.
    cell : float, optional
        Vote grid cell, pixels (default: from the maps' kernel width).
    n_candidates : int, optional
        Vote peaks scored exactly per probe (the best is polished).
    max_voters : int or None, optional
        Training features that vote per probe (the heaviest; all count in
        the exact score).
    max_features : int or None, optional
        Training features that take part per probe at all (an even subset;
        see :func:`posevote.inference.voting.search_translations`).
    progress : callable, optional
        Called with 1 after each viewpoint.
    n_threads : int, optional
        Viewpoints probed at once, each in a thread of its own (the search
        kernels release the GIL). Every viewpoint is computed on its own
        and written to its own rows, so the result does not depend on it.
    polish : bool, optional
        Polish each probe's translation to the score's peak (False: the
        exact score at the best vote cell; see
        :func:`posevote.inference.voting.search_translations`).

    Returns
    -------
    ProbeSet
    """
    if not (isinstance(n_threads, (int, np.integer)) and n_threads >= 1):
        raise ValueError(f"n_threads must be an integer >= 1, got {n_threads!r}")
    n_v = len(azimuths)
    scales = np.asarray(scales, dtype=np.float64)
    per_scale: list[TestMaps] = [] if isinstance(maps, TestMaps) else list(maps)
    if per_scale and len(per_scale) != len(scales):
        raise ValueError(f"need one TestMaps per scale: {len(per_scale)} for {len(scales)} "
                         "scales")
    score = np.zeros((n_v, len(inplanes), len(scales)))
    translation = np.zeros((n_v, len(inplanes), len(scales), 2))
    box = np.zeros((n_v, 2))

    def probe_view(v: int) -> None:
        """Probe viewpoint ``v``, writing its rows of ``box``, ``score`` and ``translation``."""
        xy, theta, weight, box[v], voters = _probe_features(
            model, float(azimuths[v]), float(elevations[v]), viewpoint_kappa=viewpoint_kappa,
            use_weights=use_weights, k1_cutoff=k1_cutoff, max_features=max_features,
            max_voters=max_voters)
        if weight.sum() <= 0:
            return
        if isinstance(maps, TestMaps):
            score[v], translation[v] = search_translations(
                maps, xy, theta, weight, inplanes=inplanes, scales=scales, cell=cell,
                n_candidates=n_candidates, polish=polish, voters=voters)
        else:
            for k, (scale_maps, factor) in enumerate(zip(per_scale, scales, strict=True)):
                sc, tr = search_translations(
                    scale_maps, xy, theta, weight, inplanes=inplanes, scales=np.ones(1),
                    cell=cell, n_candidates=n_candidates, polish=polish, voters=voters)
                score[v, :, k], translation[v, :, k] = sc[:, 0], tr[:, 0] * factor

    if n_threads == 1 or n_v < 2:
        for v in range(n_v):
            probe_view(v)
            if progress is not None:
                progress(1)
    else:
        with ThreadPoolExecutor(max_workers=min(int(n_threads), n_v)) as pool:
            for _ in pool.map(probe_view, range(n_v)):
                if progress is not None:
                    progress(1)
    return ProbeSet(azimuth=np.asarray(azimuths, dtype=float),
                    elevation=np.asarray(elevations, dtype=float),
                    inplane=np.asarray(inplanes, dtype=float), scale=np.asarray(scales, dtype=float),
                    score=score, translation=translation, box=box)


def near_scales(scales: NDArray[np.float64], scale: float, options: SearchOptions
                ) -> NDArray[np.intp]:
    """Indices of the grid ``scales`` within :data:`NEAR_SCALE_STEPS` steps of ``scale``.

    All of them when fewer than two are that near (a scale off the grid).
    """
    step = options.scale_step()
    near = np.flatnonzero(np.abs(np.log(scales) - np.log(scale))
                          <= NEAR_SCALE_STEPS * step + 1e-9)
    return near if len(near) >= 2 else np.arange(len(scales))


def probe(model: PoseModel, maps: TestMaps | Sequence[TestMaps | None], setup: SearchSetup, *,
          near: Hypothesis | None = None, size: float = 1.0,
          progress: Callable[[int], None] | None = None, polish: bool = True) -> ProbeSet:
    """Probe p(w) on the grid of ``setup`` (Fig. 2).

    Parameters
    ----------
    model : PoseModel
    maps : TestMaps or sequence of TestMaps
        From :func:`~posevote.inference.setup.search_maps` (or restricted to a window). Per-scale maps
        may hold None for scales not to be probed.
    setup : SearchSetup
    near : Hypothesis, optional
        Probe only the viewpoints within three grid steps of it, and, with
        per-scale maps, the scales of :func:`near_scales`.
    size : float, optional
        Multiplies the scale grid (an instance's training size); per-scale
        maps fix the grid, and then it is ignored.
    progress : callable, optional
        Called with 1 after each viewpoint.
    polish : bool, optional
        False leaves each probe at its best vote cell (a ranking for the
        appearance verification, which moves the boxes itself). With
        per-scale maps, polished or not, the scales between every other one
        are probed only at the best viewpoints (:data:`RANKING_VIEWPOINTS`),
        the others scoring 0; on the viewing sphere the first scales, too,
        go coarse to fine over the viewpoints (:data:`COARSE_STEPS`). With
        one set of maps, a full search (no ``near``) of six viewpoints or
        more polishes only the viewpoints near its :data:`POLISHED_MODES`
        best (:func:`_polished_near_modes`).

    Returns
    -------
    ProbeSet
    """
    opts = setup.options
    step = None if opts.viewpoint_step_deg is None else np.radians(opts.viewpoint_step_deg)
    az, el = viewpoint_grid(model, subdivisions=opts.viewpoint_subdivisions, step=step)
    if near is not None and len(az) > 3:
        dirs = viewing_direction(az, el)
        cosines = dirs @ viewing_direction(near.azimuth, near.elevation)
        gap = float(np.median(np.diff(np.sort(az)))) if np.ptp(el) < 1e-9 else np.radians(20)
        keep = cosines >= np.cos(3.0 * gap)
        if keep.sum() < 3:
            keep = np.isin(np.arange(len(az)), np.argsort(-cosines)[:3])
        az, el = az[keep], el[keep]
    inplanes, scales = opts.grid()
    if len(az) * len(inplanes) * len(scales) > MAX_PROBES:
        raise ValueError(f"the search grid has {len(az)} viewpoints x {len(inplanes)} in-plane "
                         f"angles x {len(scales)} scales, over the limit of {MAX_PROBES} "
                         "probes; use a coarser SearchOptions grid")
    given: TestMaps | list[TestMaps]
    if isinstance(maps, TestMaps):
        scales = scales * size
        given = maps
    else:
        if len(maps) != len(scales):
            raise ValueError(f"need one TestMaps (or None) per scale: {len(maps)} for "
                             f"{len(scales)} scales")
        keep = np.arange(len(scales)) if near is None else near_scales(scales, near.scale, opts)
        keep = np.array([k for k in keep if maps[k] is not None], dtype=np.intp)
        if len(keep) == 0 and near is not None:
            # A pose beside the scales that have maps (a verification's few): those.
            keep = np.array([k for k, m in enumerate(maps) if m is not None], dtype=np.intp)
        if len(keep) == 0:
            raise ValueError("no maps for the scales to probe")
        scales = scales[keep]
        given = [m for m in (maps[k] for k in keep) if m is not None]
    kw: dict[str, Any] = dict(
        inplanes=inplanes, viewpoint_kappa=setup.viewpoint_kappa, use_weights=setup.use_weights,
        k1_cutoff=K1_CUTOFF, max_voters=MAX_VOTERS, max_features=opts.max_search_features,
        n_candidates=VOTE_CANDIDATES, n_threads=setup.n_threads, polish=polish)
    strategy = search_strategy(per_scale=not isinstance(given, TestMaps), polish=polish,
                               near=near is not None, n_viewpoints=len(az),
                               n_scales=len(scales))
    if strategy == "every probe":
        return probe_poses(model, given, azimuths=az, elevations=el, scales=scales,
                           progress=progress, **kw)
    if strategy == "polish near the best":
        assert isinstance(given, TestMaps)
        return _polished_near_modes(model, given, az, el, scales, progress=progress, **kw)
    assert not isinstance(given, TestMaps)
    return _ranking_probes(model, given, az, el, scales, progress=progress, **kw)


#: The fewest viewpoints and scales for which a search saves probes (fewer: every probe).
MIN_STRATEGY_VIEWPOINTS = 6
MIN_STRATEGY_SCALES = 4


def search_strategy(*, per_scale: bool, polish: bool, near: bool, n_viewpoints: int,
                    n_scales: int) -> str:
    """How :func:`probe` covers its grid, from what the search is and what it is for.

    ======================  =============================================  ====================
    strategy                when                                           probes
    ======================  =============================================  ====================
    "polish near the best"  one set of maps, polished, a full search of    every viewpoint, only
                            :data:`MIN_STRATEGY_VIEWPOINTS` or more        those the fit of the
                                                                           best modes reads
                                                                           polished
    "ranking"               per-scale maps, :data:`MIN_STRATEGY_SCALES`    every other scale
                            scales or more, as many viewpoints             everywhere (coarse to
                                                                           fine over a sphere),
                                                                           the rest at the best
                                                                           viewpoints
    "every probe"           otherwise (a few viewpoints or scales, a       all
                            search near a pose on one set of maps, an
                            unpolished one on one set)
    ======================  =============================================  ====================

    Returns
    -------
    str
        One of the strategies above.
    """
    few = n_viewpoints < MIN_STRATEGY_VIEWPOINTS
    if not per_scale:
        return "polish near the best" if polish and not near and not few else "every probe"
    return "every probe" if few or n_scales < MIN_STRATEGY_SCALES else "ranking"


def _polished_near_modes(model: PoseModel, maps: TestMaps, az: NDArray[np.float64],
                         el: NDArray[np.float64], scales: NDArray[np.float64], *,
                         progress: Callable[[int], None] | None, **kw: Any) -> ProbeSet:
    """Every viewpoint unpolished, then those near the :data:`POLISHED_MODES` best polished.

    The polished probes are what a polished search gives them; the others
    keep the exact score at their vote cell (a cell's width from the peak at
    most), enough to rank viewpoints that no fit reads.
    """
    rough = probe_poses(model, maps, azimuths=az, elevations=el, scales=scales,
                        progress=progress, **{**kw, "polish": False})
    top = np.argsort(-rough.score.max(axis=(1, 2)), kind="stable")[:POLISHED_MODES]
    d = rough.directions
    reach = np.cos(POLISH_REACH_STEPS * probe_spacing(rough))
    score, translation = rough.score.copy(), rough.translation.copy()
    for v in np.flatnonzero((d @ d[top].T >= reach).any(axis=1)):
        xy, theta, weight, _, _ = _search_features(model, float(az[v]), float(el[v]), kw)
        if weight.sum() > 0:
            score[v], translation[v] = polish_translations(
                maps, xy, theta, weight, inplanes=kw["inplanes"], scales=scales,
                score=rough.score[v], translation=rough.translation[v])
    return replace(rough, score=score, translation=translation)


def _ranking_probes(model: PoseModel, maps: list[TestMaps], az: NDArray[np.float64],
                    el: NDArray[np.float64], scales: NDArray[np.float64], *,
                    progress: Callable[[int], None] | None, **kw: Any) -> ProbeSet:
    """Every other scale everywhere, the scales between at the best ``RANKING_VIEWPOINTS``.

    Unprobed probes score 0. A search that only ranks the probes for the
    verification needs the best ones, and the score changes little from one
    scale to the next (the search kernel is widened for half a step).
    """
    even, odd = np.arange(0, len(scales), 2), np.arange(1, len(scales), 2)
    first = _coarse_to_fine(model, [maps[k] for k in even], az, el, scales[even],
                            progress=progress, **kw)
    n_best = max(3, int(round(len(az) * RANKING_VIEWPOINTS)))
    best = np.sort(np.argsort(-first.score.max(axis=(1, 2)), kind="stable")[:n_best])
    between = probe_poses(model, [maps[k] for k in odd], azimuths=az[best],
                          elevations=el[best], scales=scales[odd], **kw)
    n_a = len(first.inplane)
    score = np.zeros((len(az), n_a, len(scales)))
    translation = np.zeros((len(az), n_a, len(scales), 2))
    score[:, :, even], translation[:, :, even] = first.score, first.translation
    rows = np.ix_(best, np.arange(n_a), odd)
    score[rows], translation[rows] = between.score, between.translation
    probed = np.zeros(score.shape, dtype=bool)
    probed[:, :, even] = first.probed if first.probed is not None else True
    probed[rows] = True
    return ProbeSet(azimuth=first.azimuth, elevation=first.elevation, inplane=first.inplane,
                    scale=np.asarray(scales, dtype=float), score=score, translation=translation,
                    box=first.box, probed=probed)


def coarse_viewpoints(az: NDArray[np.float64], el: NDArray[np.float64], separation: float
                      ) -> NDArray[np.intp]:
    """A subset of the viewpoints at least ``separation`` (radians) apart, in their order.

    Every other viewpoint lies within ``separation`` of one of the subset
    (each is left out only for being that near one already taken).
    """
    dirs = viewing_direction(az, el)
    # A hair of slack so that a regular lattice's exact multiples are taken.
    limit = np.cos(separation) + 1e-9
    chosen = np.empty_like(dirs)
    kept: list[int] = []
    for v in range(len(dirs)):
        if not kept or float((chosen[:len(kept)] @ dirs[v]).max()) <= limit:
            chosen[len(kept)] = dirs[v]
            kept.append(v)
    return np.asarray(kept, dtype=np.intp)


def _coarse_to_fine(model: PoseModel, maps: list[TestMaps], az: NDArray[np.float64],
                    el: NDArray[np.float64], scales: NDArray[np.float64], *,
                    progress: Callable[[int], None] | None, **kw: Any) -> ProbeSet:
    """Probe ``scales`` at every viewpoint of a turntable; on the sphere, coarse to fine.

    On the sphere the viewpoints :data:`COARSE_STEPS` spacings apart are
    probed first, then the others within that reach of the best
    :data:`RANKING_VIEWPOINTS` of them; the rest score 0, unprobed.
    """
    if np.ptp(el) < 1e-9 or len(az) < MIN_STRATEGY_VIEWPOINTS:
        return probe_poses(model, maps, azimuths=az, elevations=el, scales=scales,
                           progress=progress, **kw)
    dirs = viewing_direction(az, el)
    reach = COARSE_STEPS * median_spacing(dirs)
    coarse = coarse_viewpoints(az, el, reach)
    rough = probe_poses(model, maps, azimuths=az[coarse], elevations=el[coarse], scales=scales,
                        progress=progress, **kw)
    n_top = max(3, int(round(len(coarse) * RANKING_VIEWPOINTS)))
    top = coarse[np.argsort(-rough.score.max(axis=(1, 2)), kind="stable")[:n_top]]
    near = (dirs @ dirs[top].T >= np.cos(reach) - 1e-9).any(axis=1)
    near[coarse] = False
    fine = np.flatnonzero(near)
    score = np.zeros((len(az),) + rough.score.shape[1:])
    translation = np.zeros((len(az),) + rough.translation.shape[1:])
    box = np.zeros((len(az), 2))
    score[coarse], translation[coarse], box[coarse] = rough.score, rough.translation, rough.box
    if len(fine):
        rest = probe_poses(model, maps, azimuths=az[fine], elevations=el[fine], scales=scales,
                           progress=progress, **kw)
        score[fine], translation[fine], box[fine] = rest.score, rest.translation, rest.box
    probed = np.zeros(score.shape, dtype=bool)
    probed[coarse] = True
    probed[fine] = True
    for v in np.flatnonzero(~probed[:, 0, 0]):
        # The fit and the refinements read boxes everywhere (cached features).
        box[v] = _search_features(model, float(az[v]), float(el[v]), kw)[3]
    return ProbeSet(azimuth=np.asarray(az, dtype=float), elevation=np.asarray(el, dtype=float),
                    inplane=rough.inplane, scale=rough.scale, score=score,
                    translation=translation, box=box, probed=probed)
