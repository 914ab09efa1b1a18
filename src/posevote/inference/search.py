"""Pose inference (Fig. 2): probes of p(w) over viewpoint x in-plane angle x scale.

For each discrete viewpoint ``w1`` the training features of nearby training
views (pose kernel K1) are collected with vote weights ``wt_i * K1``; for
each in-plane/scale step ``w2`` the translation ``w3`` is found by voting
(:mod:`posevote.inference.voting`). The result is a :class:`ProbeSet`: the
set of (pose, score) pairs approximating p(w) at discrete probes.
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from posevote._options import Options
from posevote.features.edges import EdgeFeatures
from posevote.geometry import viewing_direction
from posevote.inference.maps import MAX_MAP_BYTES, TestMaps, prepare_test, scaled_features
from posevote.inference.voting import (
    polish_translations,
    search_translations,
    strongest_voters,
    subsample_features,
)
from posevote.model.density import PoseModel, near_views
from posevote.model.kernels import K1_CUTOFF, ORIENTATION_KAPPA
from posevote.model.morph import morphed_positions
from posevote.results import Hypothesis

#: Training features that vote per probe (the heaviest; all count in the
#: exact score): the vote only has to find the peak's neighbourhood.
MAX_VOTERS = 100
#: Vote peaks per probe whose exact score is computed; the best is polished.
VOTE_CANDIDATES = 2
#: The most probes (viewpoints x in-plane angles x scales) one search may
#: hold, and the most in-plane angles or scales: a grid past these is refused
#: before anything is allocated.
MAX_PROBES = 2_000_000
MAX_GRID_STEPS = 400
#: The re-rankings of the best probes ``SearchOptions.rerank`` names.
RERANKINGS = (None, "coverage", "template")
#: Width of the local chance level, in search kernel widths (``chance_correction``):
#: chosen on the five epfl-cv folds among 2, 4, 6 and 8 (docs/DEFAULTS.md).
CHANCE_WIDTH = 4.0
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
#: The scales a search may be given (``SearchOptions.scale_range``): below, an
#: object of the training size is a few pixels; above, its maps outgrow memory.
SCALE_LIMITS = (0.05, 20.0)
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
#: Several objects in one image: a box overlapping one already found by more
#: than this IoU is the same object found again.
OBJECT_OVERLAP = 0.3
#: Several objects: the edges this far around a found box (a share of its
#: size) go with it, so that its outline does not attract the next search.
OBJECT_MARGIN = 0.1


@dataclass(frozen=True, kw_only=True, repr=False)
class SearchOptions(Options):
    """The grid of Fig. 2 and how each probe is scored.

    Attributes
    ----------
    viewpoint_step_deg : float or None, default None
        Probe turntable models on a regular azimuth grid of this step
        instead of at the training viewpoints (dense or pooled training
        sets; :func:`viewpoint_grid`).
    viewpoint_subdivisions : int, default 1
        Probes per training-viewpoint gap: 1 probes the training viewpoints.
    inplane_range_deg : (float, float), default (0, 0)
        In-plane angles searched, degrees.
    inplane_step_deg : float, default 10.0
        Step of the in-plane search, degrees.
    scale_range : (float, float), default (0.9, 1.1)
        Scales searched, relative to the training images.
    scale_steps : int, default 3
        Scales searched (log-spaced). Keep the log-scale step near the
        in-plane step in radians when widening the range.
    object_kernel : bool, default False
        Fix the position kernel in object units: the test features are
        divided by each searched scale and searched at scale 1, so that
        small scales are not favoured by a relatively wider tolerance
        (beyond the paper).
    chance_correction : bool, default False
        Score each probe by what it explains above the local chance level:
        the search's density less its mean over orientations around each
        place, blurred at ``CHANCE_WIDTH`` kernel widths
        (:func:`posevote.inference.maps.prepare_test`; beyond the paper).
    density_cap : float or None, default None
        Saturate the search's test density at this value (a model feature
        is explained or not, however dense the edges around it); None: the
        paper's unbounded density.
    max_search_features : int or None, default None
        At most about this many training features per viewpoint take part in
        the grid search (an even subset), for pooled category models; the
        refinements read all of them.
    rerank : {None, "coverage", "template"}, default None
        Re-rank the search's best probes (beyond the paper): ``"coverage"``
        by the share of the test edges in their box that they explain
        (:mod:`posevote.inference.coverage`), ``"template"`` by how well the
        image matches the nearest training view's grey levels there
        (:mod:`posevote.inference.templates`; the templates are learnt when
        the model is fitted with it); None: by their score alone.
    """

    viewpoint_step_deg: float | None = None
    viewpoint_subdivisions: int = 1
    inplane_range_deg: tuple[float, float] = (0.0, 0.0)
    inplane_step_deg: float = 10.0
    scale_range: tuple[float, float] = (0.9, 1.1)
    scale_steps: int = 3
    object_kernel: bool = False
    chance_correction: bool = False
    density_cap: float | None = None
    max_search_features: int | None = None
    rerank: str | None = None

    def __post_init__(self) -> None:
        self._number("viewpoint_step_deg", low=0.1, high=180.0, optional=True)
        self._number("viewpoint_subdivisions", low=1, high=16, integer=True)
        low, high = self._pair("inplane_range_deg")
        if high - low >= 360:
            self._fail("inplane_range_deg", "a span under 360 degrees", self.inplane_range_deg)
        self._number("inplane_step_deg", low=0.1, high=180.0)
        low, high = self._pair("scale_range")
        if not SCALE_LIMITS[0] <= low <= high <= SCALE_LIMITS[1]:
            self._fail("scale_range", f"(low, high) with {SCALE_LIMITS[0]:g} <= low <= high "
                       f"<= {SCALE_LIMITS[1]:g}", self.scale_range)
        self._number("scale_steps", low=1, high=MAX_GRID_STEPS, integer=True)
        for name in ("object_kernel", "chance_correction"):
            self._flag(name)
        if self.rerank not in RERANKINGS:
            self._fail("rerank", f"one of {', '.join(map(repr, RERANKINGS))}", self.rerank)
        self._number("density_cap", low=0.0, high=1e6, low_open=True, optional=True)
        self._number("max_search_features", low=1, high=10_000_000, integer=True,
                     optional=True)
        n_inplane = len(self.grid()[0])
        if n_inplane > MAX_GRID_STEPS:
            self._fail("inplane_step_deg", f"a step giving at most {MAX_GRID_STEPS} in-plane "
                       f"angles over inplane_range_deg (this gives {n_inplane})",
                       self.inplane_step_deg)

    def grid(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The in-plane angles (radians, centred on the range) and scales searched (copies)."""
        inplanes, scales = self._grid
        return inplanes.copy(), scales.copy()

    @cached_property
    def _grid(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        # Worked out once per options: a search asks for it several times an image.
        a_lo, a_hi = np.radians(self.inplane_range_deg)
        step = np.radians(self.inplane_step_deg)
        n_a = int(np.floor((a_hi - a_lo) / step + 1e-9)) + 1
        inplanes = (a_lo + a_hi) / 2.0 + (np.arange(n_a) - (n_a - 1) / 2.0) * step
        lo, hi = self.scale_range
        scales = np.geomspace(lo, hi, self.scale_steps) if self.scale_steps > 1 \
            else np.array([np.sqrt(lo * hi)])
        return inplanes, scales

    def scale_step(self) -> float:
        """The grid's log-scale step (0 for one scale)."""
        scales = self.grid()[1]
        return float(np.median(np.diff(np.log(scales)))) if len(scales) > 1 else 0.0


@dataclass(frozen=True, kw_only=True)
class SearchSetup:
    """Everything a search of one fitted model needs besides the image.

    Attributes
    ----------
    options : SearchOptions
    position_sigma : float
        The narrow (refinement) position kernel, pixels at scale 1.
    edge_spacing : float
        Spacing of the test edge points, pixels (normalises phi).
    viewpoint_kappa : float
        Concentration of the pose kernel K1.
    use_weights : bool
        Use the features' weights (Eq. 4).
    n_threads : int
        Viewpoints probed at once.
    """

    options: SearchOptions
    position_sigma: float
    edge_spacing: float
    viewpoint_kappa: float
    use_weights: bool = True
    n_threads: int = 1


def search_sigma(model: PoseModel, setup: SearchSetup) -> float:
    """Position kernel width used while searching, pixels.

    A probe lies up to half a grid step from the true in-plane angle and
    scale; a feature at radius ``r`` is then displaced by about
    ``r * step / 2``. The kernel is widened by that amount (in quadrature)
    so that the probe nearest the truth keeps its score, instead of losing
    it to clutter between grid steps.
    """
    inplanes, scales = setup.options.grid()
    r = model.rms_radius * float(np.max(scales))
    d_alpha = float(np.median(np.diff(inplanes))) if len(inplanes) > 1 else 0.0
    d_log_s = setup.options.scale_step()
    return float(np.sqrt(setup.position_sigma**2 + (r * d_alpha / 2.0) ** 2
                         + (r * d_log_s / 2.0) ** 2))


def image_maps(features: EdgeFeatures, shape: tuple[int, int], setup: SearchSetup, *,
               sigma: float | None = None, scale: float = 1.0, search: bool = False,
               region: tuple[int, int, int, int] | None = None) -> TestMaps:
    """The test image tabulated at kernel width ``sigma`` (default: the narrow one).

    ``density_cap`` and the local chance level apply to the search's maps
    only: the narrow maps of the refinements keep the unsaturated density,
    whose ridges give the precise alignment. ``region`` tabulates a narrow
    map only there (:func:`posevote.inference.maps.prepare_test`).
    """
    width = setup.position_sigma if sigma is None else sigma
    local = search and setup.options.chance_correction
    return prepare_test(features, shape, position_sigma=width,
                        orientation_kappa=ORIENTATION_KAPPA,
                        edge_spacing=setup.edge_spacing / scale,
                        density_cap=setup.options.density_cap if search else None,
                        chance_width=CHANCE_WIDTH * width if local else None, region=region)


def scale_maps(features: EdgeFeatures, shape: tuple[int, int], setup: SearchSetup, *,
               sigma: float | None = None, search: bool = False,
               scales: NDArray[np.float64] | None = None) -> list[TestMaps]:
    """One set of maps per scale, the features divided by it (object units).

    ``scales`` defaults to the search grid's; a search narrowed to a few
    scales (the verification's) passes its own.
    """
    grid = setup.options.grid()[1] if scales is None else scales
    return [image_maps(*scaled_features(features, shape, float(s)), setup, sigma=sigma,
                       scale=float(s), search=search) for s in grid]


def map_bytes(shape: tuple[int, int], options: SearchOptions) -> int:
    """The most memory the search's test maps of an image of ``shape`` take, bytes (planes
    of pixels; a wide kernel's coarse grid takes less)."""
    h, w = shape
    if not options.object_kernel:
        return 16 * h * w * 4
    return sum(16 * int(np.ceil(h / s)) * int(np.ceil(w / s)) * 4 for s in options.grid()[1])


def search_maps(features: EdgeFeatures, shape: tuple[int, int], model: PoseModel,
                setup: SearchSetup) -> TestMaps | list[TestMaps]:
    """The maps the search runs on: one set, or one per scale (``object_kernel``).

    Raises
    ------
    ValueError
        If they would take more than ``MAX_MAP_BYTES`` (checked before any
        is made).
    """
    need = map_bytes(shape, setup.options)
    if need > MAX_MAP_BYTES:
        raise ValueError(f"the search's test maps of this {shape[1]} x {shape[0]} image take "
                         f"{need / 2**30:.1f} GiB, over the limit of {MAX_MAP_BYTES / 2**30:.0f} "
                         "GiB; downscale the image, or narrow SearchOptions.scale_range or "
                         "scale_steps")
    sigma = search_sigma(model, setup)
    if not setup.options.object_kernel:
        return image_maps(features, shape, setup, sigma=sigma, search=True)
    return scale_maps(features, shape, setup, sigma=sigma, search=True)


@dataclass(frozen=True, kw_only=True, eq=False)
class ProbeSet:
    """Discrete approximations of p(w) (the output of Fig. 2).

    Attributes
    ----------
    azimuth, elevation : ndarray, shape (V,)
        Probed viewpoints, radians.
    inplane : ndarray, shape (A,)
        Probed in-plane angles, radians.
    scale : ndarray, shape (S,)
        Probed scales.
    score : ndarray, shape (V, A, S)
        p(w) at the best translation of each probe.
    translation : ndarray, shape (V, A, S, 2)
        That translation: the reference point ``(u, v)``, pixels.
    box : ndarray, shape (V, 2)
        Object box width and height at each viewpoint, model units.
    probed : ndarray of bool, shape (V, A, S), or None
        The probes a ranking search probed (the others score 0 without
        having been scored); None: every probe.
    """

    azimuth: NDArray[np.float64]
    elevation: NDArray[np.float64]
    inplane: NDArray[np.float64]
    scale: NDArray[np.float64]
    score: NDArray[np.float64]
    translation: NDArray[np.float64]
    box: NDArray[np.float64]
    probed: NDArray[np.bool_] | None = None

    @cached_property
    def directions(self) -> NDArray[np.float64]:
        """Viewing direction of each probed viewpoint, shape (V, 3)."""
        return viewing_direction(self.azimuth, self.elevation)

    @cached_property
    def spacing(self) -> float:
        """Median angle between a probed viewpoint and its nearest neighbour, radians (pi
        for fewer than two); cached, as every fit of the probes' modes reads it."""
        return median_spacing(self.directions)

    def boxes(self) -> NDArray[np.float64]:
        """Box ``(x, y, w, h)`` of every probe, pixels, shape (V, A, S, 4)."""
        size = np.broadcast_to(self.box[:, None, None, :] * self.scale[None, None, :, None],
                               self.translation.shape)
        return np.concatenate([self.translation - size / 2.0, size], axis=-1)

    @property
    def turntable(self) -> bool:
        """True when every probe has the same elevation (only azimuth varies)."""
        return bool(np.ptp(self.elevation) < 1e-9) if len(self.elevation) else True


def median_spacing(directions: NDArray[np.float64]) -> float:
    """Median angle between a viewing direction and its nearest neighbour, radians (pi for
    fewer than two)."""
    if len(directions) < 2:
        return float(np.pi)
    cosines = np.clip(directions @ directions.T, -1.0, 1.0)
    np.fill_diagonal(cosines, -1.0)
    return float(np.median(np.arccos(cosines.max(axis=1))))


def probe_spacing(probes: ProbeSet) -> float:
    """Median angle between a probed viewpoint and its nearest neighbour."""
    return probes.spacing


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


@dataclass(frozen=True, kw_only=True, eq=False)
class ViewpointFeatures:
    """The training features that describe one viewpoint (psi at w1).

    Attributes
    ----------
    xy, theta : ndarray
        Object-centred features of the training views near the viewpoint.
    weight : ndarray
        Vote weights ``wt_i * K1(w1, w_i)``, normalised to sum to 1.
    box : ndarray, shape (2,)
        Object box width and height at the viewpoint, model units.
    """

    xy: NDArray[np.float64]
    theta: NDArray[np.float64]
    weight: NDArray[np.float64]
    box: NDArray[np.float64]


def viewpoint_features(model: PoseModel, azimuth: float, elevation: float, *,
                       viewpoint_kappa: float, use_weights: bool = True, k1_cutoff: float = 0.1
                       ) -> ViewpointFeatures:
    """Collect the training features of the views near a viewpoint (Eq. 1 at w1).

    Training views whose pose kernel K1 is below ``k1_cutoff`` are left out
    (the nearest view always takes part). With a morphed model (``model.shift``)
    the features move toward the viewpoint (:mod:`posevote.model.morph`).
    """
    views, k1 = near_views(model, azimuth, elevation, kappa=viewpoint_kappa, k1_cutoff=k1_cutoff)
    idx = model.features_of(views)
    w = k1[model.view[idx]] * (model.weight[idx] if use_weights else 1.0)
    total = w.sum()
    xy = model.xy[idx]
    if model.shift is not None and model.view_neighbour is not None:
        xy = morphed_positions(xy, model.shift[idx], model.view[idx], azimuth,
                               model.view_azimuth, model.view_neighbour, elevation=elevation,
                               view_elevation=model.view_elevation)
    return ViewpointFeatures(xy=xy, theta=model.theta[idx],
                             weight=w / total if total > 0 else w,
                             box=np.average(model.view_box[views], axis=0, weights=k1[views]))


# A model's search features by viewpoint: the grid's viewpoints recur in every
# image, and collecting them (1-2 ms) is a tenth of a viewpoint's searches.
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
        :func:`posevote.inference.maps.scaled_features`).
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
        From :func:`search_maps` (or restricted to a window). Per-scale maps
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
    if isinstance(given, TestMaps) and polish and near is None and len(az) >= 6:
        return _polished_near_modes(model, given, az, el, scales, progress=progress, **kw)
    if isinstance(given, TestMaps) or len(scales) < 4 or len(az) < 6:
        return probe_poses(model, given, azimuths=az, elevations=el, scales=scales,
                           progress=progress, **kw)
    return _ranking_probes(model, given, az, el, scales, progress=progress, **kw)


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
    if np.ptp(el) < 1e-9 or len(az) < 6:
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
