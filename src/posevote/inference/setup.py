"""The search's setup: its grid over in-plane angle and scale, its kernel, and its test maps.

:class:`SearchOptions` is the grid of Fig. 2 and how each probe is scored;
:class:`SearchSetup` adds the fitted model's kernels
(:class:`~posevote.scoring.score.ScoreSetup`); :func:`search_maps` tabulates
the test image at the search's widened kernel (:func:`search_sigma`), once
for every scale or once per scale (``object_kernel``), refused before
anything is allocated when they would outgrow :data:`MAX_MAP_BYTES`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from posevote._options import Options
from posevote.features.edges import EdgeFeatures
from posevote.model.density import PoseModel
from posevote.model.kernels import ORIENTATION_KAPPA
from posevote.model.training import MAX_LEVEL
from posevote.scoring.maps import MAX_MAP_BYTES, TestMaps, prepare_test, scaled_features
from posevote.scoring.score import ScoreSetup

MAX_GRID_STEPS = 400


#: The re-rankings of the best probes ``SearchOptions.rerank`` names (the template
#: re-ranking is the templates' own step, ``TemplateOptions.rerank``).
RERANKINGS = (None, "coverage")


#: Width of the local chance level, in search kernel widths (``chance_correction``):
#: chosen on the five epfl-cv folds among 2, 4, 6 and 8 (docs/DEFAULTS.md).
CHANCE_WIDTH = 4.0


#: The scales a search may be given (``SearchOptions.scale_range``): below, an
#: object of the training size is a few pixels; above, its maps outgrow memory.
SCALE_LIMITS = (0.05, 20.0)


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
        Scales searched (log-spaced; one where ``scale_range`` is one value).
        Keep the log-scale step near the in-plane step in radians when
        widening the range.
    object_kernel : bool, default False
        Fix the position kernel in object units: the test features are
        divided by each searched scale and searched at scale 1, so that
        small scales are not favoured by a relatively wider tolerance
        (beyond the paper).
    chance_correction : bool, default False
        Score each probe by what it explains above the local chance level:
        the search's density less its mean over orientations around each
        place, blurred at ``CHANCE_WIDTH`` kernel widths
        (:func:`posevote.scoring.maps.prepare_test`; beyond the paper).
    density_cap : float or None, default None
        Saturate the search's test density at this value (a model feature
        is explained or not, however dense the edges around it); None: the
        paper's unbounded density.
    max_search_features : int or None, default None
        At most about this many training features per viewpoint take part in
        the grid search (an even subset), for pooled category models; the
        refinements read all of them.
    rerank : {None, "coverage"}, default None
        ``"coverage"``: re-rank the search's best probes by the share of the
        test edges in their box that they explain (beyond the paper;
        :mod:`posevote.inference.coverage`); None: by their score alone. (By
        the grey levels: ``TemplateOptions.rerank``.)
    calibration : (float, float, float), default (1, 0, 0)
        ``(a, b, c)``: the best mode's probability is
        ``sigmoid(a logit(p) + b ln(score) + c)`` of its share ``p`` of the
        search's posterior over viewpoints and its detection score (the contrast
        where measured, else its score)
        (:func:`posevote.refinement.probability.calibrated`); each preset's
        is fitted on its development folds, on the estimates it reports (over
        its ``min_score``) or on every one, whichever calibrates the reported
        ones better (``benchmarks/calibrate_probability.py``).
        ``(1, 0, 0)``: the share.
    image_levels : tuple of float, default (1.0,)
        The image is searched at each of these sizes (1: as given; 0.5: halved,
        with a quarter of the test features, where an object twice the size
        ``scale_range`` covers looks as one it covers; 1.8: as given, with the
        model learnt from the training views shrunk by 1.8 at fit, where an
        object 1/1.8 the size looks as one it covers), and the level whose
        best mode's ``detection_score`` is highest is kept, mapped back to the image
        (:func:`posevote.pipeline.estimate_levels`). A frame under 640 x 480
        pixels is searched as given only.
    contrast : bool, default False
        Measure each mode's contrast, its score over the spread of what its
        pose scores elsewhere in the frame (:mod:`posevote.scoring.contrast`),
        and let ``min_score`` and the choice of image level read it instead
        of the score: for objects that fill a small part of their frame.
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
    calibration: tuple[float, float, float] = (1.0, 0.0, 0.0)
    image_levels: tuple[float, ...] = (1.0,)
    contrast: bool = False

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
        for name in ("object_kernel", "chance_correction", "contrast"):
            self._flag(name)
        if self.rerank not in RERANKINGS:
            hint = " (the template re-ranking is TemplateOptions.rerank)" \
                if self.rerank == "template" else ""
            self._fail("rerank", f"one of {', '.join(map(repr, RERANKINGS))}{hint}", self.rerank)
        self._number("density_cap", low=0.0, high=1e6, low_open=True, optional=True)
        self._number("max_search_features", low=1, high=10_000_000, integer=True,
                     optional=True)
        self._calibration()
        self._image_levels()
        n_inplane = len(self.grid()[0])
        if n_inplane > MAX_GRID_STEPS:
            self._fail("inplane_step_deg", f"a step giving at most {MAX_GRID_STEPS} in-plane "
                       f"angles over inplane_range_deg (this gives {n_inplane})",
                       self.inplane_step_deg)

    def _image_levels(self) -> None:
        expected = f"1 to 4 distinct sizes from 0.1 to {MAX_LEVEL:g}"
        value = self.image_levels
        if isinstance(value, (str, bytes, dict)):
            self._fail("image_levels", expected, value)
        try:
            levels = tuple(sorted({float(v) for v in value}, reverse=True))
        except (TypeError, ValueError):
            self._fail("image_levels", expected, value)
        if not (1 <= len(levels) == len(tuple(value)) <= 4
                and all(0.1 <= v <= MAX_LEVEL for v in levels)):
            self._fail("image_levels", expected, value)
        object.__setattr__(self, "image_levels", levels)

    def _calibration(self) -> None:
        expected = "(a, b, c): three finite numbers, 0 <= a <= 100, |b|, |c| <= 100"
        value = self.calibration
        try:
            a, b, c = (float(v) for v in value)
        except (TypeError, ValueError):
            self._fail("calibration", expected, value)
        if isinstance(value, (str, bytes, dict)) or not (
                0.0 <= a <= 100.0 and abs(b) <= 100.0 and abs(c) <= 100.0):
            self._fail("calibration", expected, value)
        object.__setattr__(self, "calibration", (a, b, c))

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
        # One scale where the range is one value: repeated scales are no grid to fit on.
        scales = np.geomspace(lo, hi, self.scale_steps) if self.scale_steps > 1 and hi > lo \
            else np.array([np.sqrt(lo * hi)])
        return inplanes, scales

    def scale_step(self) -> float:
        """The grid's log-scale step (0 for one scale)."""
        scales = self.grid()[1]
        return float(np.median(np.diff(np.log(scales)))) if len(scales) > 1 else 0.0


@dataclass(frozen=True, kw_only=True)
class SearchSetup(ScoreSetup):
    """Everything a search of one fitted model needs besides the image: the scoring
    setup (:class:`~posevote.scoring.score.ScoreSetup`) and the search's grid.

    Attributes
    ----------
    options : SearchOptions
    """

    options: SearchOptions


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


def _search_image_maps(features: EdgeFeatures, shape: tuple[int, int], setup: SearchSetup, *,
                       sigma: float, scale: float = 1.0) -> TestMaps:
    """The test image tabulated at the search's kernel width ``sigma``, saturated at
    ``density_cap`` and less the local chance level (``chance_correction``): the
    narrow maps of the refinements (:func:`posevote.scoring.score.narrow_maps`) keep
    the unsaturated density, whose ridges give the precise alignment."""
    local = setup.options.chance_correction
    return prepare_test(features, shape, position_sigma=sigma,
                        orientation_kappa=ORIENTATION_KAPPA,
                        edge_spacing=setup.edge_spacing / scale,
                        density_cap=setup.options.density_cap,
                        chance_width=CHANCE_WIDTH * sigma if local else None)


def scale_maps(features: EdgeFeatures, shape: tuple[int, int], setup: SearchSetup, *,
               sigma: float, scales: NDArray[np.float64] | None = None) -> list[TestMaps]:
    """The search's maps, one set per scale, the features divided by it (object units).

    ``scales`` defaults to the search grid's.
    """
    grid = setup.options.grid()[1] if scales is None else scales
    return [_search_image_maps(*scaled_features(features, shape, float(s)), setup, sigma=sigma,
                               scale=float(s)) for s in grid]


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
        return _search_image_maps(features, shape, setup, sigma=sigma)
    return scale_maps(features, shape, setup, sigma=sigma)

