"""The estimate as a sequence of named steps (Sec. II-B, and each idea beyond the paper).

An estimate starts from the test image's edge features (:func:`begin`) and
runs the steps of :data:`STEPS` that its settings switch on, in that order,
each a plain function from one frozen :class:`EstimateState` to the next:

====================  ==============================  ===========================================
step                  switch                          what it does
====================  ==============================  ===========================================
search                always                          probes of p(w) on the grid (Fig. 2)
rerank by coverage    ``search.rerank="coverage"``    the best probes times the test edges they
                                                      explain
rerank by template    ``templates.rerank``            the best probes times their grey-level
                                                      match
verify                ``appearance.candidates``       the best probes' boxes by HOG; the search
                                                      again inside the winner's box
modes                 always                          the profile's peaks, as their best probes
fit                   ``refine.fit``                  each mode fitted to the probes around it
                                                      (Sec. II-B)
rescale               ``refine.rescale``              the best mode's scale on the narrow kernel
local refinement      ``refine.local``                the best mode on the exact p(w)
half-turn             ``templates.half_turn``         the best mode or its half-turn
share scale           ``refine.share_scale``          the scale from both directions
recognise             ``recognition``                 the instance, and its own estimate
                                                      (Sec. III-B)
appearance            ``appearance``                  the box regressed, the nearest view's
                                                      viewpoint
keypoints             ``refine.keypoints``            the object where the texture finds it
                                                      (the mode's box holding none), its side
                                                      and viewpoint from keypoints matched to
                                                      the views'
outline               ``refine.outline``              each mode's box from its views' outline
contrast              ``search.contrast``             each mode's score over its frame's
                                                      background spread, less its box's
                                                      places in the frame
reject                always (``min_score``)          the modes whose detection score is at
                                                      least ``min_score``
probabilities         always                          each mode's probability
lookalike             always                          how alike the object looks there to
                                                      another side of it (``ambiguous``)
place                 always                          ``R_cam_obj``, ``t_cam_obj`` (a camera)
====================  ==============================  ===========================================

A switch reads only its own step's option. What several steps read is built
once, where it is first needed, and handed on: the search's maps, the narrow
maps (:func:`~posevote.scoring.score.narrow_maps`), the grey image in
single precision and the whole image's keypoints. The steps run once per
image level (:func:`level_states`: the image resized, or as given with the
views shrunk), and the level of the best detection score is kept
(:func:`estimate_levels`). A step may also say what it needs from training or from
an earlier step (:attr:`Step.needs`): the templates, the appearance model,
or probes that are only ranked (the verification moves the boxes itself, so
the search need not polish them); :func:`artefacts` collects them, and
``fit`` learns what the steps ask for. docs/DESIGN.md describes each step.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, fields, replace
from functools import partial
from typing import Any, Generic, TypeVar

import cv2
import numpy as np
from numpy.typing import NDArray

from posevote._options import Options
from posevote.appearance import AppearanceOptions
from posevote.appearance.model import AppearanceCollector
from posevote.appearance.refine import appearance_refine, front_back_share
from posevote.appearance.verify import verify
from posevote.camera import Camera, place_all
from posevote.features.edges import (
    BUDGET_AREA,
    EdgeFeatures,
    EdgeOptions,
    extract_edges,
    frame_budget,
    without_box,
)
from posevote.geometry import box_iou, rotate_points
from posevote.inference.coverage import rerank_by_coverage
from posevote.inference.probes import ProbeSet
from posevote.inference.search import probe
from posevote.inference.setup import SearchOptions, SearchSetup, search_maps
from posevote.keypoints.model import KeypointCollector
from posevote.keypoints.refine import image_keypoints, keypoint_locate, keypoint_refine
from posevote.model.density import origin_offset, view_average
from posevote.model.kernels import K1_CUTOFF, KernelOptions
from posevote.model.outline import outline_at, outline_box
from posevote.model.pruning import PruningPreset, resolve_preset
from posevote.model.training import AppearanceModel, CollectorFactory, TrainedModel
from posevote.recognition import RecognitionOptions
from posevote.recognition.refine import recognize
from posevote.refinement import RefineOptions
from posevote.refinement.fitting import FIT_RADIUS_STEPS, find_modes, refine_mode
from posevote.refinement.local import PoseWeights, local_refine, polish_pose, rescale_mode
from posevote.refinement.lookalike import LookalikeCollector
from posevote.refinement.probability import scored_viewpoints, with_probabilities
from posevote.refinement.share import share_scale
from posevote.results import Hypothesis, PoseEstimate
from posevote.scoring.contrast import mode_contrast
from posevote.scoring.maps import TestMaps
from posevote.scoring.score import narrow_maps, score_options
from posevote.templates import TemplateOptions
from posevote.templates.halfturn import half_turn
from posevote.templates.match import correlation_weights, gradient_similarity, rerank_by_template
from posevote.templates.model import TemplateCollector

#: Several objects in one image: a box overlapping one already found by more
#: than this IoU is the same object found again.
OBJECT_OVERLAP = 0.3
#: Several objects: the edges this far around a found box (a share of its
#: size) go with it, so that its outline does not attract the next search.
OBJECT_MARGIN = 0.1

T = TypeVar("T")


class Built(Generic[T]):
    """A value several steps read, built on first use and then kept."""

    def __init__(self, build: Callable[[], T]) -> None:
        self._build: Callable[[], T] | None = build
        self._value: T | None = None

    def __call__(self) -> T:
        if self._build is not None:
            self._value, self._build = self._build(), None
        return self._value  # type: ignore[return-value]


@dataclass(frozen=True, kw_only=True)
class Settings:
    """The estimator's parameters (:class:`~posevote.PoseEstimator`'s), checked: what the
    steps read, and the training's own switches."""

    weights: bool
    morph_views: bool
    edges: EdgeOptions
    kernel: KernelOptions
    search: SearchOptions
    refine: RefineOptions
    prune: str | PruningPreset | None
    templates: TemplateOptions | None
    recognition: RecognitionOptions | None
    appearance: AppearanceOptions | None
    max_modes: int
    min_score: float
    n_jobs: int

    def __post_init__(self) -> None:
        for name in ("weights", "morph_views"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
        resolve_preset(self.prune)
        for f in fields(self):
            kind, value = OPTION_GROUPS.get(f.name), getattr(self, f.name)
            optional = f.name in OPTIONAL_GROUPS
            if kind is not None and not (isinstance(value, kind) or (optional and value is None)):
                raise TypeError(f"{f.name} must be a {kind.__name__}"
                                f"{' or None' if optional else ''}, got {value!r}")
        for name, high in (("max_modes", 100), ("n_jobs", 256)):
            value = getattr(self, name)
            if not (isinstance(value, (int, np.integer)) and not isinstance(value, bool)
                    and 1 <= value <= high):
                raise ValueError(f"{name} must be an integer in [1, {high}], got {value!r}")
        if not (isinstance(self.min_score, (int, float)) and np.isfinite(self.min_score)):
            raise ValueError(f"min_score must be a finite number, got {self.min_score!r}")

    @classmethod
    def of(cls, params: dict[str, Any]) -> Settings:
        """The settings among an estimator's parameters (``get_params(deep=False)``).

        Raises
        ------
        TypeError, ValueError
            A group of the wrong type; a flag, count, threshold or pruning out of range.
        """
        return cls(**{f.name: params[f.name] for f in fields(cls)})


#: The option group of each grouped setting, and those that None switches off.
OPTION_GROUPS: dict[str, type[Options]] = {
    "edges": EdgeOptions, "kernel": KernelOptions, "search": SearchOptions,
    "refine": RefineOptions, "templates": TemplateOptions, "recognition": RecognitionOptions,
    "appearance": AppearanceOptions}
OPTIONAL_GROUPS = ("templates", "recognition", "appearance")


@dataclass(frozen=True, kw_only=True, eq=False)
class EstimateState:
    """What the steps know of one estimate; each step returns the next state.

    Attributes
    ----------
    settings : Settings
    trained : TrainedModel
        The fitted model (searched and full), its kernels and extensions.
    setup : SearchSetup
        The search's grid and the kernels every score reads.
    needs : frozenset of str
        What the steps to run need (:func:`artefacts`).
    image : ndarray, shape (H, W)
        The grey test image.
    features : EdgeFeatures
        Its edge features (after the verification: those in the verified box).
    camera : Camera or None
    narrow : Built
        The narrow maps of ``features``, built when a step first reads them.
    grey : Built
        ``image`` in single precision (the HOG descriptors read it).
    keypoints : Built
        The whole image's keypoints, where the keypoint step looks for the object (shared
        by the levels that search the same image).
    search_maps : TestMaps or list of (TestMaps or None), or None
        The search's maps (after the verification: restricted to its box).
    probes : ProbeSet or None
    modes : tuple of int
        Each mode's best probed viewpoint, best first.
    hypotheses : tuple of Hypothesis
        The modes' poses, best first.
    verified_box : (x, y, w, h) or None
        The verification winner's regressed box.
    instance, instance_margin : str, float
        The recognised instance and its margin.
    front_back : float or None
        The best mode's share when the appearance step chose its viewpoint
        (its side against the half-turned one by HOG) or the keypoint step
        turned it (its view's inliers against the found side's); None: its
        share of the search's profile.
    top_score : float
        The best mode's score before the rejection.
    progress : callable or None
        Called with 1 after each viewpoint the search probes.
    """

    settings: Settings
    trained: TrainedModel
    setup: SearchSetup
    needs: frozenset[str]
    image: NDArray[np.float64]
    features: EdgeFeatures
    camera: Camera | None = None
    narrow: Built[TestMaps]
    grey: Built[NDArray[np.float32]]
    keypoints: Built[tuple[NDArray[np.float64], NDArray[np.uint8]]]
    search_maps: TestMaps | list[TestMaps | None] | list[TestMaps] | None = None
    probes: ProbeSet | None = None
    modes: tuple[int, ...] = ()
    hypotheses: tuple[Hypothesis, ...] = ()
    verified_box: tuple[float, float, float, float] | None = None
    instance: str = ""
    instance_margin: float = math.nan
    front_back: float | None = None
    top_score: float = 0.0
    progress: Callable[[int], None] | None = field(default=None, repr=False)

    @property
    def shape(self) -> tuple[int, int]:
        """The image's shape (H, W)."""
        return int(self.image.shape[0]), int(self.image.shape[1])

    @property
    def weigh(self) -> PoseWeights | None:
        """What weighs the poses the local refinement compares (``templates.weigh``)."""
        t = self.settings.templates
        return correlation_weights(self.trained.model, self.image) if t and t.weigh else None

    def with_features(self, features: EdgeFeatures) -> EstimateState:
        """The state on other features: their narrow maps are new."""
        return replace(self, features=features,
                       narrow=Built(partial(narrow_maps, features, self.shape, self.setup)))

    def with_hypotheses(self, hypotheses: Sequence[Hypothesis]) -> EstimateState:
        return replace(self, hypotheses=tuple(hypotheses))

    def best_replaced(self, best: Hypothesis) -> EstimateState:
        """The state with the best mode's pose replaced."""
        return replace(self, hypotheses=(best, *self.hypotheses[1:]))


# -- the steps, in the order they run --------------------------------------------------

def search(state: EstimateState) -> EstimateState:
    """Probe p(w) on the grid (Fig. 2): polished, unless a later step only ranks the probes."""
    model = state.trained.model
    maps = state.search_maps if state.search_maps is not None else search_maps(
        state.features, state.shape, model, state.setup)
    probes = probe(model, maps, state.setup, progress=state.progress,
                   polish="ranked probes" not in state.needs)
    return replace(state, search_maps=maps, probes=probes)


def rerank_coverage(state: EstimateState) -> EstimateState:
    """The best probes' scores times the share of the test edges in their box they explain."""
    assert state.probes is not None and state.search_maps is not None
    maps: Any = state.search_maps
    return replace(state, probes=rerank_by_coverage(state.probes, state.trained.model, maps,
                                                    state.setup))


def rerank_template(state: EstimateState) -> EstimateState:
    """The best probes' scores times their grey-level match with the nearest template."""
    assert state.probes is not None
    return replace(state, probes=rerank_by_template(state.probes, state.trained.model,
                                                    state.image))


def verify_boxes(state: EstimateState) -> EstimateState:
    """The best probes verified by appearance; the search again inside the winner's box, or
    polished over the whole image where no candidate could be verified."""
    assert state.probes is not None and state.search_maps is not None
    found = None
    if state.probes.score.any():
        options = state.settings.appearance
        assert options is not None
        maps: Any = state.search_maps
        found = verify(state.probes, state.grey(), state.features, maps, state.trained.model,
                       _appearance_model(state), options, state.setup)
    if found is None:
        again = replace(state, needs=state.needs - {"ranked probes"})
        return run(again, [s for s in STEPS[:STEPS.index(VERIFY)]
                           if s.active(state.settings)])
    features, maps, probes, box = found
    return replace(state.with_features(features), search_maps=maps, probes=probes,
                   verified_box=box)


def modes(state: EstimateState) -> EstimateState:
    """The peaks of the score profile over viewpoints, each as its best probe."""
    assert state.probes is not None
    found = find_modes(state.probes, max_modes=state.settings.max_modes)
    return replace(state, modes=tuple(found), hypotheses=tuple(
        refine_mode(state.probes, v, fit=False, radius_steps=FIT_RADIUS_STEPS) for v in found))


def fit(state: EstimateState) -> EstimateState:
    """Each mode's pose fitted to the probes around it (Sec. II-B)."""
    assert state.probes is not None
    return state.with_hypotheses([refine_mode(state.probes, v, fit=True,
                                              radius_steps=FIT_RADIUS_STEPS)
                                  for v in state.modes])


def rescale(state: EstimateState) -> EstimateState:
    """The best mode's scale and position on the narrow kernel (models of one instance)."""
    model = state.trained.model
    if not state.hypotheses or len(model.instance_names) > 1:
        return state
    return state.best_replaced(rescale_mode(state.hypotheses[0], model, state.narrow(),
                                            state.setup))


def local(state: EstimateState) -> EstimateState:
    """The best mode refined on the exact p(w) with the narrow kernel (``"polish"``), its
    viewpoint too (``"profile"``), in object units where the search was."""
    if not state.hypotheses:
        return state
    assert state.probes is not None
    return state.best_replaced(local_refine(
        state.probes, state.modes[0], state.hypotheses[0], state.trained.model, state.setup,
        profile=state.settings.refine.local == "profile", narrow=state.narrow,
        scale_step=state.setup.options.scale_step(),
        object_units=not isinstance(state.search_maps, TestMaps), features=state.features,
        shape=state.shape, weigh=state.weigh))


def check_half_turn(state: EstimateState) -> EstimateState:
    """The best mode, or its half-turn where that explains the image better; a turned pose
    keeps the found one as the next mode."""
    if not state.hypotheses:
        return state
    model, hyps = state.trained.model, state.hypotheses
    pose, turned = half_turn(hyps[0], model, state.narrow(), state.setup,
                             correlation_weights(model, state.image),
                             resemble=partial(gradient_similarity, model, state.image),
                             features=state.features, shape=state.shape)
    return state.with_hypotheses([pose, *hyps][:state.settings.max_modes] if turned
                                 else [pose, *hyps[1:]])


def scale_by_share(state: EstimateState) -> EstimateState:
    """The best mode's scale where its narrow score times its share of the edges peaks."""
    if not state.hypotheses:
        return state
    return state.best_replaced(share_scale(state.hypotheses[0], state.trained.model,
                                           state.narrow(), state.setup))


def recognise(state: EstimateState) -> EstimateState:
    """The instance recognised and its own estimate first (models of several instances); its
    modes refined as the estimate refines its own (``refine.fit``, ``refine.local``)."""
    trained, options = state.trained, state.settings.recognition
    if not state.hypotheses or len(trained.model.instance_names) <= 1:
        return state
    assert options is not None and state.search_maps is not None
    maps: Any = state.search_maps
    hyps, instance, margin = recognize(list(state.hypotheses), state.features,
                                       trained.full_model, maps, state.narrow(), state.setup,
                                       options, fit=state.settings.refine.fit,
                                       local=state.settings.refine.local)
    return replace(state.with_hypotheses(hyps), instance=instance, instance_margin=margin)


def appearance(state: EstimateState) -> EstimateState:
    """The best mode's box regressed (or the verified one kept), its viewpoint the nearest
    training view's by HOG."""
    if not state.hypotheses:
        return state
    options = state.settings.appearance
    assert options is not None
    trained = _appearance_model(state)
    best = appearance_refine(state.hypotheses[0], state.grey(), state.trained.model, trained,
                             options, verified_box=state.verified_box)
    return replace(state.best_replaced(best), front_back=front_back_share(
        best, state.grey(), state.trained.model, trained))


def keypoints(state: EstimateState) -> EstimateState:
    """The object placed where the whole image's keypoints find it when the best mode's box
    holds none of its texture (a model of one instance), then turned to the side its
    texture shows and its viewpoint read between the views, from keypoints matched to
    theirs (a model of one instance, or the recognised instance's views); a located or
    turned pose is polished on the edges and keeps the found one as the next mode, and its
    share of the texture's evidence is the best mode's share."""
    if not state.hypotheses:
        return state
    full = state.trained.full_model
    names = full.instance_names
    if len(names) > 1 and state.instance not in names:
        return state                  # another instance's texture is no evidence
    views = (np.flatnonzero(full.view_instance == names.index(state.instance))
             if len(names) > 1 else None)
    upright = tuple(state.settings.search.inplane_range_deg) == (0.0, 0.0)
    hyps = state.hypotheses
    # A recognised instance was recognised at the mode's box: its place is the mode's.
    located = (keypoint_locate(hyps[0], full, state.image, upright=upright,
                               keypoints=state.keypoints()) if len(names) == 1 else None)
    front_back = state.front_back
    if located is not None:
        # The texture found the object away from the mode (kept next); the edges polish it,
        # and its side's share is the texture's (the profile peaked at the mode).
        hyps = (_polished(located[0], state, upright=upright), *hyps)
        front_back = located[1]
    pose, share = keypoint_refine(hyps[0], full, state.image, views=views, upright=upright)
    if share is None:
        return replace(state.with_hypotheses([pose, *hyps[1:]][:state.settings.max_modes]),
                       front_back=front_back)
    # Turned: polished on the edges at its own view as a located pose is (the scale was the
    # other side's fit); the texture's evidence for the side is the share the probability
    # reads.
    pose = _polished(pose, state, upright=upright)
    return replace(state.with_hypotheses([pose, *hyps][:state.settings.max_modes]),
                   front_back=share)


def _polished(pose: Hypothesis, state: EstimateState, *, upright: bool) -> Hypothesis:
    """A pose the keypoints placed or turned, polished on the edges (its in-plane angle held
    where the search holds the object upright)."""
    return polish_pose(pose, state.trained.model, state.narrow(), turn=not upright,
                       **score_options(state.setup))


def outline(state: EstimateState) -> EstimateState:
    """Each mode's box from its views' outline, where the model has outlines (tighter than
    the views' box turned)."""
    return state.with_hypotheses([_outlined(h, state.trained) for h in state.hypotheses])


def contrast(state: EstimateState) -> EstimateState:
    """Each mode's score over the spread of what its pose scores elsewhere in the frame."""
    if not state.hypotheses:
        return state
    maps = state.narrow()
    options = score_options(state.setup)
    return state.with_hypotheses([
        replace(h, contrast=mode_contrast(h, state.trained.model, maps, state.shape, **options))
        for h in state.hypotheses])


def reject(state: EstimateState) -> EstimateState:
    """The modes whose detection score (contrast where measured) is at least ``min_score``
    (0 keeps every contrast, which is never below 0); the best is kept (what a rejected
    image scored)."""
    hyps = state.hypotheses
    return replace(state, top_score=max((h.detection_score for h in hyps), default=0.0),
                   hypotheses=tuple(h for h in hyps
                                    if h.detection_score >= state.settings.min_score))


def probabilities(state: EstimateState) -> EstimateState:
    """Each kept mode's probability: its share of the score profile over viewpoints (the
    best mode's: its front/back share where the appearance chose its viewpoint), the best
    mode's calibrated with its score."""
    assert state.probes is not None
    return state.with_hypotheses(with_probabilities(
        list(state.hypotheses), state.probes, state.settings.search.calibration,
        best_share=state.front_back))


def lookalike(state: EstimateState) -> EstimateState:
    """Each kept mode's likeness to another side of the object: its views'
    ``view_lookalike`` averaged with K1 at its viewpoint (not measured: NaN, a model file
    of an earlier posevote)."""
    trained = state.trained
    alike = trained.model.view_lookalike
    if alike is None:
        return state
    return state.with_hypotheses([
        replace(h, lookalike=float(view_average(trained.model, alike, h.azimuth, h.elevation,
                                                kappa=trained.viewpoint_kappa,
                                                k1_cutoff=K1_CUTOFF)))
        for h in state.hypotheses])


def place(state: EstimateState) -> EstimateState:
    """Each mode in the camera's frame, given a camera (``R_cam_obj``, ``t_cam_obj``)."""
    if state.camera is None:
        return state
    trained = state.trained
    return state.with_hypotheses(place_all(
        state.hypotheses, state.camera, reference_size_px=trained.model.reference_size,
        object_height_m=trained.object_height_m,
        anchors=[_origin(h, trained) for h in state.hypotheses]))


def _appearance_model(state: EstimateState) -> AppearanceModel:
    if state.trained.appearance is None:
        raise ValueError("the appearance stages need the appearance model learnt when the "
                         "model is fitted; fit (or retrain) with appearance set")
    return state.trained.appearance


def _outlined(hypothesis: Hypothesis, trained: TrainedModel) -> Hypothesis:
    found = outline_at(trained.model, hypothesis.azimuth, hypothesis.elevation,
                       kappa=trained.viewpoint_kappa, k1_cutoff=K1_CUTOFF)
    if found is None:
        return hypothesis
    return replace(hypothesis, box=outline_box(found, hypothesis.position, hypothesis.scale,
                                               hypothesis.inplane))


def _origin(hypothesis: Hypothesis, trained: TrainedModel
            ) -> tuple[float, float, float] | None:
    """The image of the object's origin under a hypothesis and its depth factor (None: the
    box centre at the object's depth)."""
    offset = origin_offset(trained.model, hypothesis.azimuth, hypothesis.elevation,
                           kappa=trained.viewpoint_kappa, k1_cutoff=K1_CUTOFF)
    if offset is None:
        return None
    u, v = hypothesis.position + hypothesis.scale * rotate_points(offset[:2],
                                                                   hypothesis.inplane)
    return float(u), float(v), float(offset[2])


# -- the list of steps -------------------------------------------------------------------

def _always(_: Settings) -> bool:
    return True


def _nothing(_: Settings) -> frozenset[str]:
    return frozenset()


@dataclass(frozen=True, kw_only=True)
class Step:
    """One step of the estimate.

    Attributes
    ----------
    name : str
    run : callable
        ``EstimateState -> EstimateState``.
    switch : str
        The option that switches it on, as a user sets it.
    active : callable
        Whether the settings switch it on (it reads that option only).
    needs : callable
        What it needs from training (``"templates"``, ``"appearance"``) or of the
        search (``"ranked probes"``), under the settings.
    when : str
        What the data must be for the step to act (else it hands the state on).
    """

    name: str
    run: Callable[[EstimateState], EstimateState]
    switch: str = "always"
    active: Callable[[Settings], bool] = _always
    needs: Callable[[Settings], frozenset[str]] = _nothing
    when: str = ""


VERIFY = Step(name="verify", run=verify_boxes, switch="appearance.candidates",
              active=lambda s: s.appearance is not None and s.appearance.candidates > 0,
              needs=lambda s: frozenset({"appearance", "ranked probes"}))

#: Every step, in the order they run.
STEPS: tuple[Step, ...] = (
    Step(name="search", run=search),
    Step(name="rerank by coverage", run=rerank_coverage, switch="search.rerank",
         active=lambda s: s.search.rerank == "coverage"),
    Step(name="rerank by template", run=rerank_template, switch="templates.rerank",
         active=lambda s: s.templates is not None and s.templates.rerank,
         needs=lambda s: frozenset({"templates"})),
    VERIFY,
    Step(name="modes", run=modes),
    Step(name="fit", run=fit, switch="refine.fit", active=lambda s: s.refine.fit),
    Step(name="rescale", run=rescale, switch="refine.rescale", active=lambda s: s.refine.rescale,
         when="one instance"),
    Step(name="local refinement", run=local, switch="refine.local",
         active=lambda s: s.refine.local is not None,
         needs=lambda s: frozenset({"templates"} if s.templates and s.templates.weigh else ())),
    Step(name="half-turn", run=check_half_turn, switch="templates.half_turn",
         active=lambda s: s.templates is not None and s.templates.half_turn,
         needs=lambda s: frozenset({"templates"})),
    Step(name="share scale", run=scale_by_share, switch="refine.share_scale",
         active=lambda s: s.refine.share_scale),
    Step(name="recognise", run=recognise, switch="recognition",
         active=lambda s: s.recognition is not None, when="several instances"),
    Step(name="appearance", run=appearance, switch="appearance",
         active=lambda s: s.appearance is not None, needs=lambda s: frozenset({"appearance"})),
    Step(name="keypoints", run=keypoints, switch="refine.keypoints",
         active=lambda s: s.refine.keypoints, needs=lambda s: frozenset({"keypoints"}),
         when="one instance, or a recognised one"),
    Step(name="outline", run=outline, switch="refine.outline", active=lambda s: s.refine.outline),
    Step(name="contrast", run=contrast, switch="search.contrast",
         active=lambda s: s.search.contrast),
    Step(name="reject", run=reject, switch="always (min_score)"),
    Step(name="probabilities", run=probabilities),
    Step(name="lookalike", run=lookalike, needs=lambda s: frozenset({"lookalike"})),
    Step(name="place", run=place, when="a camera"),
)
#: The steps that make the probes (:meth:`~posevote.PoseEstimator.probe` runs these).
SEARCH_STEPS = ("search", "rerank by coverage", "rerank by template")


def active_steps(settings: Settings, names: Sequence[str] | None = None) -> list[Step]:
    """The steps the settings switch on, in order (only those of ``names``, if given)."""
    return [s for s in STEPS if s.active(settings) and (names is None or s.name in names)]


def artefacts(settings: Settings, steps: Sequence[Step] | None = None) -> frozenset[str]:
    """What the steps need (:attr:`Step.needs`), those the settings switch on by default."""
    chosen = active_steps(settings) if steps is None else steps
    return frozenset().union(*(s.needs(settings) for s in chosen))


#: What learns each thing a step needs from training.
COLLECTORS: dict[str, CollectorFactory] = {"templates": TemplateCollector,
                                           "appearance": AppearanceCollector,
                                           "keypoints": KeypointCollector,
                                           "lookalike": LookalikeCollector}


def collectors(needs: frozenset[str]) -> list[CollectorFactory]:
    """The view collectors that learn what the steps need (:func:`artefacts`)."""
    return [COLLECTORS[name] for name in sorted(needs) if name in COLLECTORS]


def held(trained: TrainedModel) -> frozenset[str]:
    """What a fitted model holds besides its edges, which a partial fit learns for the new
    views too (the views' likeness to other sides, read from the edges alone, whatever it
    holds)."""
    full = trained.full_model
    found = {"lookalike"} | ({"templates"} if full.view_template is not None else set())
    found |= {"keypoints"} if full.keypoint_xy is not None else set()
    return frozenset(found | ({"appearance"} if trained.appearance is not None else set()))


def describe(settings: Settings) -> list[str]:
    """The steps the settings run, in order, as labels: the name, the local refinement's
    kind, and in brackets what the data must be for a step to act."""
    out = []
    for s in active_steps(settings):
        label = s.name
        if s.name == "local refinement":
            label += f" ({settings.refine.local})"
        out.append(label + (f" [{s.when}]" if s.when else ""))
    return out


# -- running them ----------------------------------------------------------------------

def search_setup(settings: Settings, trained: TrainedModel) -> SearchSetup:
    """The search's setup of a fitted model under the settings."""
    return SearchSetup(options=settings.search, position_sigma=settings.kernel.position_sigma,
                       edge_spacing=settings.edges.spacing,
                       viewpoint_kappa=trained.viewpoint_kappa, use_weights=settings.weights,
                       n_threads=settings.n_jobs)


def begin(settings: Settings, trained: TrainedModel, image: NDArray[np.float64],
          features: EdgeFeatures, *, steps: Sequence[Step], camera: Camera | None = None,
          progress: Callable[[int], None] | None = None) -> EstimateState:
    """The state before the first of ``steps``, on the image's features."""
    setup = search_setup(settings, trained)
    shape = (int(image.shape[0]), int(image.shape[1]))
    return EstimateState(settings=settings, trained=trained, setup=setup,
                         needs=artefacts(settings, steps), image=image, features=features,
                         camera=camera, progress=progress,
                         narrow=Built(partial(narrow_maps, features, shape, setup)),
                         grey=Built(partial(np.asarray, image, dtype=np.float32)),
                         keypoints=Built(partial(image_keypoints, image)))


def run(state: EstimateState, steps: Sequence[Step]) -> EstimateState:
    """Run ``steps`` in order."""
    for step in steps:
        state = step.run(state)
    return state


def result(done: EstimateState, start: float) -> PoseEstimate:
    """The estimate the steps came to; its time counts from ``start``
    (a :func:`time.perf_counter` reading)."""
    kept = done.hypotheses
    assert done.probes is not None
    return PoseEstimate(found=bool(kept), best=kept[0] if kept else None, modes=kept,
                        n_test_features=len(done.features),
                        seconds=time.perf_counter() - start,
                        instance=done.instance if kept else "",
                        instance_margin=done.instance_margin, top_score=done.top_score,
                        viewpoint_scores=scored_viewpoints(done.probes))


def check_max_objects(max_objects: int) -> None:
    """Refuse a count of objects that is not an integer in [1, 100]."""
    if not (isinstance(max_objects, int) and not isinstance(max_objects, bool)
            and 1 <= max_objects <= 100):
        raise ValueError(f"max_objects must be an integer in [1, 100], got {max_objects!r}")


def estimate_objects(state: EstimateState, steps: Sequence[Step], max_objects: int, *,
                     start: float) -> list[PoseEstimate]:
    """Up to ``max_objects`` objects, best first, each found by ``steps`` from ``state``
    (a state before the first step), on the edges the objects before left.

    After each object, the edges in its box (grown by :data:`OBJECT_MARGIN`) are
    taken away and the steps run again on the rest; a box overlapping one
    already found (IoU over :data:`OBJECT_OVERLAP`) is not kept. Each object's
    time counts from the end of the one before (the first's from ``start``).
    """
    found: list[PoseEstimate] = []
    features = state.features
    while len(found) < max_objects and len(features):
        estimate = result(run(state.with_features(features), steps), start)
        start = time.perf_counter()
        if estimate.best is None:
            break
        if all(box_iou(estimate.best.box, f.best.box) <= OBJECT_OVERLAP
               for f in found if f.best):
            found.append(estimate)
        features = without_box(features, estimate.best.box, grow=OBJECT_MARGIN)
    return found


# --- image levels: coarse scales first ---------------------------------------


def image_levels(settings: Settings, shape: tuple[int, ...]) -> tuple[float, ...]:
    """The levels searched in an image of ``shape``: ``SearchOptions.image_levels``, the
    reduced ones only in a frame of at least :data:`BUDGET_AREA` (a smaller crop is taken
    to be framed around its object: halved, it offered larger false matches)."""
    levels = settings.search.image_levels
    if shape[0] * shape[1] >= BUDGET_AREA:
        return levels
    return tuple(level for level in levels if level == 1.0) or (1.0,)


def level_image(image: NDArray[np.float64], level: float) -> NDArray[np.float64]:
    """The image at ``level`` of its size (area-averaged); itself at 1 and over (a level over
    1 shrinks the model's views instead: :meth:`TrainedModel.at_level`)."""
    if level >= 1.0:
        return image
    h, w = image.shape[:2]
    size = (max(1, int(round(w * level))), max(1, int(round(h * level))))
    return np.asarray(cv2.resize(np.asarray(image, dtype=np.float32), size,
                                 interpolation=cv2.INTER_AREA), dtype=np.float64)


def level_camera(camera: Camera | None, level: float) -> Camera | None:
    """The camera of an image resized by ``level`` (pixel centres kept; no distortion: the
    image was undistorted before)."""
    if camera is None or level >= 1.0:
        return camera
    return Camera(fx=camera.fx * level, fy=camera.fy * level,
                  cx=(camera.cx + 0.5) * level - 0.5, cy=(camera.cy + 0.5) * level - 0.5)


def level_edges(edges: EdgeOptions, shape: tuple[int, ...], level: float) -> EdgeOptions:
    """The edge options at ``level``: the image's test budget times the level's area, so that
    the points are as many per object as at full size and the scores of the levels compare."""
    if level >= 1.0 or edges.max_test_features is None:
        return edges
    budget = frame_budget(edges, shape)
    assert budget is not None
    return replace(edges, max_test_features=max(1, int(round(budget * level * level))))


def from_level(estimate: PoseEstimate, level: float) -> PoseEstimate:
    """An estimate made at ``level``, in the image's pixels and the model's scale (the
    camera-frame pose is the same: the level's camera was the image's, scaled; over 1, the
    image was itself and the views shrunk by the level)."""
    if level == 1.0:
        return estimate
    zoom = min(level, 1.0)

    def back(h: Hypothesis) -> Hypothesis:
        u, v = ((c + 0.5) / zoom - 0.5 for c in h.position)
        x, y, w, bh = h.box
        return replace(h, position=(u, v), scale=h.scale / level,
                       box=((x + 0.5) / zoom - 0.5, (y + 0.5) / zoom - 0.5, w / zoom,
                            bh / zoom))

    modes = tuple(back(h) for h in estimate.modes)
    best = None if estimate.best is None else back(estimate.best)
    return replace(estimate, best=best, modes=modes)


def level_states(settings: Settings, trained: TrainedModel, image: NDArray[np.float64],
                 edges: EdgeOptions, steps: Sequence[Step], *, camera: Camera | None = None
                 ) -> Iterator[tuple[float, EstimateState]]:
    """Each level (:func:`image_levels`) and the state before the first of ``steps`` there:
    the image at the level of its size searched with the model, or over 1 the image itself
    with the views shrunk by the level (its edges, keypoints and narrow maps read once for
    the levels that share it)."""
    first: dict[float, EstimateState] = {}
    for level in image_levels(settings, image.shape):
        zoom = min(level, 1.0)
        if zoom in first:
            shared = first[zoom]
            state = begin(settings, trained.at_level(level), shared.image, shared.features,
                          steps=steps, camera=shared.camera)
            # The keypoints read the image, the narrow maps its features and the kernel only.
            same = (state.setup.position_sigma, state.setup.edge_spacing) == (
                shared.setup.position_sigma, shared.setup.edge_spacing)
            state = replace(state, keypoints=shared.keypoints,
                            narrow=shared.narrow if same else state.narrow)
        else:
            scaled = level_image(image, zoom)
            state = first[zoom] = begin(
                settings, trained.at_level(level), scaled,
                extract_edges(scaled, level_edges(edges, image.shape, zoom), training=False),
                steps=steps, camera=level_camera(camera, zoom))
        yield level, state


def estimate_levels(settings: Settings, trained: TrainedModel, image: NDArray[np.float64],
                    edges: EdgeOptions, steps: Sequence[Step], *, camera: Camera | None = None,
                    start: float) -> PoseEstimate:
    """The estimate of the level (:func:`image_levels`) whose best mode's detection score
    (``top_score``) is highest, in the image's pixels; its time counts from ``start``."""
    kept: PoseEstimate | None = None
    for level, state in level_states(settings, trained, image, edges, steps, camera=camera):
        estimate = from_level(result(run(state, steps), start), level)
        if kept is None or estimate.top_score > kept.top_score:
            kept = estimate
    assert kept is not None
    return replace(kept, seconds=time.perf_counter() - start)


def objects_at_levels(settings: Settings, trained: TrainedModel, image: NDArray[np.float64],
                      edges: EdgeOptions, steps: Sequence[Step], max_objects: int, *,
                      camera: Camera | None = None, start: float) -> list[PoseEstimate]:
    """:func:`estimate_objects` at each level, merged: best score first, a box overlapping
    one kept (IoU over :data:`OBJECT_OVERLAP`) dropped, at most ``max_objects``."""
    found: list[PoseEstimate] = []
    for level, state in level_states(settings, trained, image, edges, steps, camera=camera):
        found += [from_level(e, level)
                  for e in estimate_objects(state, steps, max_objects, start=start)]
    if len(image_levels(settings, image.shape)) == 1:
        return found
    kept: list[PoseEstimate] = []
    for estimate in sorted(found, key=lambda e: -e.best.detection_score if e.best else 0.0):
        assert estimate.best is not None
        if all(box_iou(estimate.best.box, k.best.box) <= OBJECT_OVERLAP
               for k in kept if k.best):
            kept.append(estimate)
    return kept[:max_objects]
