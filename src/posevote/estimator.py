"""The estimator: training (Sec. II-A, II-C) and estimation (Sec. II-B) in one object.

How the defaults were chosen
----------------------------
Every default below was chosen by cross-validation on *training* views
only: on COIL-100, models trained on the views at 0, 40, ..., 320 degrees
and tested on the training views in between (20, 60, ... degrees), for the
16 objects of ``../shared/data``; the COIL test views (5, 10, 15, ...
degrees off the training views) were not used to choose anything. The
script is ``benchmarks/tune_coil_cv.py``; ``docs/TUNING.md`` has its output.
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import binary_dilation

from posevote.data.images import as_gray_float, read_image, read_mask
from posevote.features.edges import EdgeFeatures, box_mask, detect_edges
from posevote.geometry import angular_error, box_centre, box_iou, viewing_direction
from posevote.inference.recognition import explained_fraction, recognition_margin
from posevote.inference.search import ProbeSet, probe_poses, viewpoint_grid
from posevote.inference.verification import (
    background_boxes,
    box_descriptor,
    box_offsets,
    crop_box,
    descriptor_length,
    jittered_boxes,
    jittered_nearest_view,
    nearest_view,
    regress_described,
    train_box_regression,
    train_objectness,
    verify_candidates,
    window_shape,
)
from posevote.inference.voting import TestMaps, prepare_test, restrict_maps, scaled_features
from posevote.model.density import PoseModel, build_model
from posevote.model.kernels import kappa_for_width
from posevote.model.modelfile import load_model, save_model
from posevote.model.morph import ViewCrops, turntable_neighbours, view_shifts
from posevote.model.pruning import PruningPreset, prune_model, resolve_preset
from posevote.model.weights import feature_weights
from posevote.refinement.fitting import VIEW_SHAPE, find_modes, probe_spacing, refine_mode
from posevote.refinement.local import (
    polish_pose,
    profile_refine,
    rank_refined,
    rescale_anchor,
)
from posevote.results import Hypothesis, PoseEstimate

ImageLike = str | Path | NDArray


class _Appearance:
    """Collects the training images' box descriptors for the verification during ``fit``.

    With the descriptor window known from the start (every box given), each
    image's descriptors are computed at once; otherwise (boxes from masks or
    whole images) the crops are kept until every box, hence the window, is
    known. With ``regression``, boxes jittered around each training box are
    described too, with the offsets back to it: the samples of the box
    regression (``appearance_refine``).
    """

    def __init__(self, boxes: NDArray[np.float64], *, regression: bool = False) -> None:
        known = bool(np.all(np.isfinite(boxes)) and np.all(boxes[:, 2:] > 0))
        self.window: tuple[int, int] | None = window_shape(boxes[:, 2:]) if known else None
        self.rng = np.random.default_rng(0)   # background boxes: same data, same model
        # A generator of its own, so that the background boxes do not depend on it.
        self.jitter_rng = np.random.default_rng(1) if regression else None
        self.views: list[NDArray[np.float32] | None] = []
        self.backgrounds: list[NDArray[np.float32] | None] = []
        self.jittered: list[NDArray[np.float32] | None] = []
        self.offsets: list[NDArray[np.float64]] = []
        self.azimuths: list[float] = []

    def _describe(self, image: NDArray[np.float64], box: Sequence[float]
                  ) -> NDArray[np.float32] | None:
        if self.window is not None:
            return box_descriptor(image, box, self.window)
        return crop_box(image, box).astype(np.float32)

    def add(self, image: NDArray[np.float64], box: Sequence[float], azimuth: float) -> None:
        """Describe one training image's box, some background boxes and jittered boxes of it."""
        self.views.append(self._describe(image, box))
        self.backgrounds += [self._describe(image, b)
                             for b in background_boxes(image.shape, box, self.rng)]
        if self.jitter_rng is not None:
            for b in jittered_boxes(box, self.jitter_rng):
                self.jittered.append(self._describe(image, b))
                self.offsets.append(box_offsets(b, box))
                self.azimuths.append(azimuth)

    def finish(self, sizes: NDArray[np.float64]
               ) -> tuple[tuple[int, int], NDArray[np.float32], NDArray[np.float64] | None,
                          NDArray[np.float64] | None]:
        """The window, the views' descriptors, the classifier and the box regression.

        Descriptors are zeros where a box is too small; the regression is None
        without ``regression``.
        """
        window = self.window if self.window is not None else window_shape(sizes)

        def stack(items: list[NDArray[np.float32] | None]) -> NDArray[np.float32]:
            out = np.zeros((len(items), descriptor_length(window)), dtype=np.float32)
            for i, item in enumerate(items):
                if item is not None and self.window is None:
                    item = box_descriptor(item, (0, 0, item.shape[1], item.shape[0]), window)
                if item is not None:
                    out[i] = item
            return out

        views, negatives = stack(self.views), stack(self.backgrounds)
        objectness = train_objectness(views[np.any(views != 0, axis=1)],
                                      negatives[np.any(negatives != 0, axis=1)])
        regressor = None
        if self.jitter_rng is not None:
            samples = stack(self.jittered)
            ok = np.any(samples != 0, axis=1)
            if ok.sum() >= 2:
                regressor = train_box_regression(samples[ok], np.array(self.offsets)[ok],
                                                 np.array(self.azimuths)[ok])
        return window, views, objectness, regressor


#: Half width at half maximum of K1, in training-view spacings, for models
#: fitted with ``morph_views`` and no ``viewpoint_bandwidth_deg`` (0.5
#: otherwise). Chosen on the rendered turntables at the COIL protocol's
#: offsets (``benchmarks/tune_rendered.py``, two probes per gap): median /
#: mean error 1.11 / 1.52 degrees at 0.625, 1.02 / 1.81 at 0.75, 1.15 / 1.96
#: at 0.875, 1.47 / 3.71 at 1.5 (docs/TUNING.md).
MORPH_BANDWIDTH = 0.75


class NotFittedError(RuntimeError):
    """Raised when an estimator is used before :meth:`PoseEstimator.fit`."""


def _load(image: ImageLike, *, name: str) -> NDArray[np.float64]:
    if isinstance(image, (str, Path)):
        return read_image(image)
    return as_gray_float(image, name=name)


class PoseEstimator:
    """Continuous 3D pose of an object in a single image (Teney & Piater 2013).

    Parameters
    ----------
    weights : bool, default True
        Weight training features by pose specificity (Eq. 4).
    fitting : bool, default True
        Refine each mode by local distribution fitting (Sec. II-B).
    local_refinement : bool, default False
        For the best mode, maximise the exact p(w) with the narrow kernel
        over in-plane angle, scale and translation at each nearby viewpoint,
        fit the viewpoint to these maximised scores, and polish the result
        (beyond the paper; :func:`posevote.refinement.local.profile_refine`).
    fit_radius_steps : float, default 2.5
        Viewpoints within this many probe spacings of a mode take part in
        its distribution fit (and in the local refinement's profile).
    fit_view_shape : float, default 0.6
        Exponent of the viewpoint term of that fit: 1 is the paper's von
        Mises-Fisher kernel, smaller values a sharper peak that matches the
        probe scores' fall-off, so the fitted viewpoint is not pulled toward
        the training views (:mod:`posevote.refinement.fitting`).
    refine_modes : int, default 1
        With ``local_refinement``, this many of the best modes are refined,
        and they are ranked again by their refined (narrow-kernel) scores;
        the others follow in search order. 3 gained on the clutter
        self-test, whose true poses are training views (which flatters
        narrow scores), and on the clean COIL cross-validation; it was
        neutral on the cluttered cross-validation and the epfl-single
        development set, and lost on the test protocols
        (``docs/TUNING.md``).
    narrow_scale : bool, default True
        With ``object_kernel``, ``local_refinement`` and ``fitting``, the
        best mode's scale is first chosen again among the search's scales
        with the narrow kernel in object units, above chance
        (:func:`posevote.refinement.local.rescale_anchor`), and the local
        refinement works in that scale's frame. The search's wide kernel
        blurs the object's inner detail, so that under occlusion a model
        shrunk onto the visible part scores as well as the right one.
        Chosen on the clutter self-test and the cluttered COIL
        cross-validation (``docs/TUNING.md``).
    interpolate_alignment : bool, default False
        With ``local_refinement`` and ``fitting`` on a turntable model, the
        estimate's in-plane angle, scale and position are interpolated,
        linearly in azimuth, between the alignments polished at the two
        probed viewpoints on either side of the fitted azimuth, instead of
        polishing the blend of their features there
        (:func:`posevote.refinement.local.interpolate_alignment`). Halfway
        between training views 40 degrees apart (the cluttered COIL
        cross-validation) it put twice as many correct poses within 5 px
        and cut their in-plane error from 7.9 to 1.3 degrees; at training
        views it lost 11 points of positions within 5 px, and at the COIL
        protocol's offsets (rendered development set) it was neutral, so
        it is off (``docs/TUNING.md``). The azimuth is the same either way.
    morph_views : bool, default False
        Training: measure, by optical flow between neighbouring turntable
        views of each instance, where every training feature moves to in
        the next and previous view, so that between training views the
        features of psi move with the object instead of blending two
        misaligned copies (:mod:`posevote.model.morph`; beyond the paper).
        Takes effect when the model is fitted; with it, probe the gaps too
        (``viewpoint_subdivisions=2``). On the epfl-single development run
        (cars 2-10, frames 9-24 degrees apart) that cut the median / mean
        error from 2.39 / 6.4 to 1.36 / 3.6 degrees for 1.6 times the time;
        with views 40 degrees apart (the COIL cross-validations) the flow is
        poor and it lost (``docs/TUNING.md``).
    refine_scale_steps : float or None, default 1.0
        The local refinement (with ``fitting``) keeps the scale within this
        many steps of the search's scale grid (at least 5% per step) of the
        mode's best probe; None leaves it free. Its narrow score is not
        corrected for chance, and in clutter it grows as the model shrinks
        onto dense edges. 1.0 was chosen on the clutter self-test
        (``docs/TUNING.md``).
    position_sigma : float, default 3.0
        Combined appearance kernel width in position, pixels at scale 1.
    orientation_kappa : float, default 8.0
        Combined appearance kernel concentration in (doubled) orientation.
    viewpoint_bandwidth_deg : float or None, default None
        Half width at half maximum of the pose kernel K1 on viewpoints;
        None sets it to half the median spacing of the training viewpoints
        (:data:`MORPH_BANDWIDTH` spacings with ``morph_views``).
    viewpoint_subdivisions : int, default 1
        Probes per training-viewpoint gap (turntable models): 1 probes the
        training viewpoints only.
    viewpoint_step_deg : float or None, default None
        Probe turntable models on a regular azimuth grid of this step
        instead of at the training viewpoints (for dense or pooled
        training sets; see :func:`posevote.inference.search.viewpoint_grid`).
    inplane_range_deg : (float, float), default (0, 0)
        Range of in-plane angles searched, degrees.
    inplane_step_deg : float, default 10.0
        Step of the in-plane search, degrees.
    scale_range : (float, float), default (0.9, 1.1)
        Range of scales searched, relative to the training images.
    scale_steps : int, default 3
        Number of scales searched (log-spaced). When widening
        ``scale_range``, keep the log-scale step near the in-plane step in
        radians (0.7-1.3 with 10-degree steps: 5 scales). In clutter a
        finer grid pays: the cluttered COIL benchmark searches 7 scales
        with 5-degree steps
        (:data:`posevote.evaluation.synthetic.CLUTTER_SEARCH`).
    edge_sigma : float, default 1.0
        Canny smoothing, pixels.
    edge_thresholds : (float, float), default (0.02, 0.05)
        Canny hysteresis thresholds, grey levels per pixel.
    edge_spacing : float, default 2.0
        Minimum spacing of edge points, pixels.
    max_train_features : int, default 300
        Feature budget per training view.
    max_test_features : int or None, default 2500
        Feature budget per test image (None: spacing only).
    clutter_sigma : float or None, default None
        Weight test edge points by their local orientation coherence and
        crowding at this scale (pixels), so that contours outvote texture;
        None: the paper's unweighted test density.
    coherence_floor : float, default 0.3
        Test edge points at or below this coherence are ignored.
    crowding_limit : float, default 1.0
        Test edge points up to this crowding (local edge density relative to
        a lone contour) keep their full weight; denser ones are discounted.
    density_cap : float or None, default None
        Saturate the search's test density phi at this value (a model
        feature is explained or not, however dense the edges around it);
        None: the paper's unbounded density. For cluttered scenes searched
        over a wide scale range, 0.5 with ``object_kernel`` and
        ``chance_correction`` was best in the cluttered COIL
        cross-validation (``docs/TUNING.md``; beyond the paper).
    contrast : float, default 0.0
        Subtract this fraction of the orientation-averaged test density from
        each orientation's density, so that texture matching every
        orientation explains nothing (0: the paper's density).
    object_kernel : bool, default False
        Fix the position kernel width in object units rather than image
        pixels: the test features are divided by each searched scale and
        searched at scale 1 (a pyramid), so that small scales are not
        favoured by a relatively wider tolerance (beyond the paper).
    chance_correction : bool, default False
        With ``object_kernel``, score each scale by the fraction explained
        above its chance level (see
        :func:`posevote.inference.search.probe_poses`).
    k1_cutoff : float, default 0.1
        Training views whose pose kernel K1 is below this do not take part in
        a viewpoint's probe.
    vote_cell : float or None, default None
        Vote grid cell, pixels (None: two-thirds of the search kernel width).
    max_voters : int or None, default 200
        Training features that vote per probe (an even subset); all of them
        count in the exact score.
    max_search_features : int or None, default None
        At most about this many training features per viewpoint take part in
        the grid search at all (an even subset); None: all. For pooled
        category models, whose viewpoints gather thousands of features. The
        instance refinement's search uses the subset too; the local
        refinement and the recognition scores read all of them.
    vote_candidates : int, default 2
        Vote peaks per probe whose exact score is computed; the best of
        them is polished to the pixel.
    prune : {None, "moderate", "aggressive"}, default None
        Prune the pooled model by clustering (Sec. III-A) with a named
        preset (:data:`posevote.model.pruning.PRESETS`); the search then
        runs on the cluster centres, while instance recognition and
        refinement use the full model.
    prune_pose_std_deg, prune_appearance_std : float or None, default None
        Override the preset's knobs (maximum within-cluster standard
        deviation in viewpoint, degrees, and in appearance, kernel widths);
        setting either without ``prune`` starts from ``"moderate"``.
    recognize_instance : bool, default True
        For models of several instances: score each instance at the
        category estimate (Eqs. 5-6) and, when one wins by
        ``instance_margin``, re-estimate near it with that instance's full
        model (Sec. III-B).
    instance_margin : float, default 1.05
        The winner's score must be at least this multiple of the runner-up's
        (chosen by cross-validation on COIL training views, seen instances
        and instances left out of the model alike:
        ``benchmarks/tune_category_cv.py --margins``).
    recognition_modes : int, default 2
        Instances are scored at this many of the best category modes (a
        front/back confusion of the category can be an instance's right
        pose); the instance is refined at the mode where it scored best.
    instance_search : bool, default True
        Beyond the paper: instead of scoring the instances at the category's
        modes and re-estimating near them (``False``, the paper's Sec.
        III-B), each instance's full model estimates the pose on its own,
        over all viewpoints and on the scale grid centred on the instance's
        training size (a grid centred on the median instance misses the
        small and large ones, and a near search cannot undo the category's
        front/back confusions); the instances are then scored at their own
        estimates (Eqs. 5-6) and, with ``instance_margin``, the winner's
        estimate is kept. About 1.6 times the time per image on the COIL
        categories (2 to 4 instances). Chosen by the COIL category
        cross-validation on training views
        (``benchmarks/tune_category_cv.py``, docs/TUNING.md): sums of
        medians / means over seen and left-out instances 31.4 / 104.7 ->
        26.3 / 65.3 degrees. With per-scale search maps
        (``object_kernel``) the scale grid stays the category's.
    verify_candidates : int, default 0
        Verify this many of the search's best probes by the appearance of
        their box (:mod:`posevote.inference.verification`; HOG descriptors
        of the training views near each probe's viewpoint) and re-estimate
        inside the box of the best-verified one, enlarged by
        ``verify_margin``, near its viewpoint; 0: off (the paper's search).
        For full cluttered frames of categories (beyond the paper; see
        ``docs/TUNING.md``).
    verify_margin : float, default 0.25
        The re-estimation keeps the test edges within the verified box
        grown by this fraction of its width and height on every side.
    verify_shortlist : int, default 10
        Of the verified candidates, only the ones that a linear classifier
        of the descriptors (trained on the training boxes against random
        boxes of the training images that miss the object) finds most
        object-like are compared with the training views.
    verify_overlap : float, default 0.0
        The re-estimation inside the verified box keeps only the probes
        whose box overlaps the verified one by at least this intersection
        over union; 0: any box within the grown window.
    verify_tolerance_deg : float or None, default None
        A verified candidate's descriptor is compared with the training
        views within this angle of its viewpoint; None: one probe spacing.
        With regressed boxes (``appearance_refine``) the descriptor can
        correct a viewpoint that is a few grid steps off: 40 degrees (four
        steps of the EPFL grid) in the EPFL category protocols
        (``docs/TUNING.md``).
    verify_objectness_weight : float, default 0.0
        The verified candidates are ranked by their descriptor's distance to
        the nearest training view minus this times the classifier's score
        (how object-like the box looks); 0: the distance alone. With
        ``verify_shortlist`` as large as ``verify_candidates`` every
        candidate is compared and the classifier only weighs in. 0.5 in the
        EPFL category protocols: on epfl-cv (every 4th frame) it took the
        cars found from 86.8 to 91.6% (``docs/TUNING.md``).
    appearance_refine : bool, default False
        Beyond the paper, for dense training views of a category in full
        frames (on in the EPFL category protocols): the best mode's box is
        moved toward the object by ridge regressions of its HOG descriptor
        (the verification's), learned when the model is fitted from boxes
        jittered around the training boxes, one per azimuth range; then its
        viewpoint becomes that of the training view whose descriptor is
        nearest to the regressed box's, among the views within
        ``appearance_window_deg`` of the estimate
        (:func:`posevote.inference.verification.regress_described`,
        :func:`~posevote.inference.verification.nearest_view`). With
        ``verify_candidates``, the short-listed candidates are judged on
        their regressed boxes too, the search again runs inside the
        winner's, and the winner's regressed box is the one kept and
        described (the appearance chose it; the mode found again inside it
        by the edges is not regressed anew). The edge votes find the car
        and tell its front from its back; the descriptor of a well-placed
        box pins the viewpoint down.
        Takes effect when the model is fitted. The viewpoint is a training
        view's: with training views far apart (COIL's 20 degrees) it is
        coarser than the fit. On epfl-cv (every 4th frame) it took the
        median / mean error from 15.0 / 46.0 to 7.2 / 38.5 degrees, the
        share under 45 degrees from 71.3 to 74.3% and the cars found from
        77.0 to 81.1%; with ``verify_tolerance_deg=40`` too, 7.2 / 35.3
        degrees, 76.7% and 82.4%, and verifying 80 candidates with a short
        list of 15, 6.6 / 32.0 degrees, 79.1% and 82.1%; keeping the
        winner's box, 5.7 / 31.1 degrees, 80.4% and 86.8%
        (``docs/TUNING.md``).
    appearance_window_deg : float, default 45.0
        With ``appearance_refine``, the training views within this angle of
        the estimate compete for the nearest descriptor (front/back
        confusions are left to the edges: on epfl-cv's every 8th frame the
        nearest view of all lost 1.2 degrees of median and 0.7 points under
        45 degrees, 60 degrees gained one frame; ``docs/TUNING.md``).
    appearance_jitter : float, default 0.0
        With ``appearance_refine``, the nearest training view is found for
        the kept box and for its 26 neighbours shifted by this fraction of
        its width and height and scaled by one plus or minus it, and the
        viewpoint is the medoid of their 27 nearest views
        (:func:`posevote.inference.verification.jittered_nearest_view`;
        beyond the paper); 0: the kept box's nearest view alone. 0.05 in the
        EPFL category protocols: on epfl-cv's every 8th frame it took the
        median error from 5.11 to 4.52 degrees (0.03: 4.55, 0.08: 4.62;
        ``docs/TUNING.md``).
    max_modes : int, default 3
        Modes reported per image.
    min_score : float, default 0.0
        Below this best score the estimate is "not found".
    n_jobs : int, default 1
        Threads that probe viewpoints at once during an estimate (the
        search kernels release the GIL): the time of one estimate on a
        machine with several cores, not its result, which is the same for
        every value. The benchmarks and protocols run one process per core
        with 1 (``benchmarks/time_threads.py`` measures the speed-up).
    """

    def __init__(
        self,
        *,
        weights: bool = True,
        fitting: bool = True,
        local_refinement: bool = False,
        fit_radius_steps: float = 2.5,
        fit_view_shape: float = VIEW_SHAPE,
        refine_modes: int = 1,
        narrow_scale: bool = True,
        refine_scale_steps: float | None = 1.0,
        interpolate_alignment: bool = False,
        morph_views: bool = False,
        position_sigma: float = 3.0,
        orientation_kappa: float = 8.0,
        viewpoint_bandwidth_deg: float | None = None,
        viewpoint_subdivisions: int = 1,
        viewpoint_step_deg: float | None = None,
        inplane_range_deg: tuple[float, float] = (0.0, 0.0),
        inplane_step_deg: float = 10.0,
        scale_range: tuple[float, float] = (0.9, 1.1),
        scale_steps: int = 3,
        edge_sigma: float = 1.0,
        edge_thresholds: tuple[float, float] = (0.02, 0.05),
        edge_spacing: float = 2.0,
        max_train_features: int = 300,
        max_test_features: int | None = 2500,
        clutter_sigma: float | None = None,
        coherence_floor: float = 0.3,
        crowding_limit: float = 1.0,
        density_cap: float | None = None,
        contrast: float = 0.0,
        object_kernel: bool = False,
        chance_correction: bool = False,
        k1_cutoff: float = 0.1,
        vote_cell: float | None = None,
        max_voters: int | None = 200,
        max_search_features: int | None = None,
        vote_candidates: int = 2,
        prune: str | None = None,
        prune_pose_std_deg: float | None = None,
        prune_appearance_std: float | None = None,
        recognize_instance: bool = True,
        instance_margin: float = 1.05,
        recognition_modes: int = 2,
        instance_search: bool = True,
        verify_candidates: int = 0,
        verify_margin: float = 0.25,
        verify_shortlist: int = 10,
        verify_overlap: float = 0.0,
        verify_tolerance_deg: float | None = None,
        verify_objectness_weight: float = 0.0,
        appearance_refine: bool = False,
        appearance_window_deg: float = 45.0,
        appearance_jitter: float = 0.0,
        max_modes: int = 3,
        min_score: float = 0.0,
        n_jobs: int = 1,
    ) -> None:
        self.weights = weights
        self.fitting = fitting
        self.local_refinement = local_refinement
        self.fit_radius_steps = fit_radius_steps
        self.fit_view_shape = fit_view_shape
        self.refine_modes = refine_modes
        self.narrow_scale = narrow_scale
        self.refine_scale_steps = refine_scale_steps
        self.interpolate_alignment = interpolate_alignment
        self.morph_views = morph_views
        self.position_sigma = position_sigma
        self.orientation_kappa = orientation_kappa
        self.viewpoint_bandwidth_deg = viewpoint_bandwidth_deg
        self.viewpoint_subdivisions = viewpoint_subdivisions
        self.viewpoint_step_deg = viewpoint_step_deg
        self.inplane_range_deg = inplane_range_deg
        self.inplane_step_deg = inplane_step_deg
        self.scale_range = scale_range
        self.scale_steps = scale_steps
        self.edge_sigma = edge_sigma
        self.edge_thresholds = edge_thresholds
        self.edge_spacing = edge_spacing
        self.max_train_features = max_train_features
        self.max_test_features = max_test_features
        self.clutter_sigma = clutter_sigma
        self.coherence_floor = coherence_floor
        self.crowding_limit = crowding_limit
        self.density_cap = density_cap
        self.contrast = contrast
        self.object_kernel = object_kernel
        self.chance_correction = chance_correction
        self.k1_cutoff = k1_cutoff
        self.vote_cell = vote_cell
        self.max_voters = max_voters
        self.max_search_features = max_search_features
        self.vote_candidates = vote_candidates
        self.prune = prune
        self.prune_pose_std_deg = prune_pose_std_deg
        self.prune_appearance_std = prune_appearance_std
        self.recognize_instance = recognize_instance
        self.instance_margin = instance_margin
        self.recognition_modes = recognition_modes
        self.instance_search = instance_search
        self.verify_candidates = verify_candidates
        self.verify_margin = verify_margin
        self.verify_shortlist = verify_shortlist
        self.verify_overlap = verify_overlap
        self.verify_tolerance_deg = verify_tolerance_deg
        self.verify_objectness_weight = verify_objectness_weight
        self.appearance_refine = appearance_refine
        self.appearance_window_deg = appearance_window_deg
        self.appearance_jitter = appearance_jitter
        self.max_modes = max_modes
        self.min_score = min_score
        self.n_jobs = n_jobs

    # -- scikit-learn style parameter access ------------------------------------
    def get_params(self) -> dict[str, Any]:
        """Hyper-parameters as a dict (JSON-serialisable)."""
        names = [p for p in inspect.signature(type(self).__init__).parameters if p != "self"]
        return {n: (list(v) if isinstance(v, tuple) else v)
                for n in names for v in [getattr(self, n)]}

    def set_params(self, **params: Any) -> PoseEstimator:
        """Set hyper-parameters; unknown names raise ``ValueError``."""
        valid = self.get_params()
        for name, value in params.items():
            if name not in valid:
                raise ValueError(f"unknown parameter {name!r}; valid: {', '.join(sorted(valid))}")
            setattr(self, name, tuple(value) if isinstance(value, list) else value)
        return self

    def _validate_params(self) -> None:
        positive = ("position_sigma", "orientation_kappa", "inplane_step_deg", "edge_sigma",
                    "edge_spacing", "fit_radius_steps", "fit_view_shape",
                    "appearance_window_deg")
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        for name in ("viewpoint_subdivisions", "scale_steps", "max_train_features", "max_modes",
                     "vote_candidates", "recognition_modes", "refine_modes", "verify_shortlist",
                     "n_jobs"):
            value = getattr(self, name)
            if not (isinstance(value, (int, np.integer)) and value >= 1):
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        for name in ("max_voters", "max_search_features", "max_test_features"):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, (int, np.integer)) and value >= 1):
                raise ValueError(f"{name} must be an integer >= 1 or None, got {value!r}")
        lo, hi = self.scale_range
        if not 0 < lo <= hi:
            raise ValueError(f"scale_range must satisfy 0 < low <= high, got {self.scale_range}")
        a_lo, a_hi = self.inplane_range_deg
        if not (np.isfinite(a_lo) and np.isfinite(a_hi) and a_lo <= a_hi and a_hi - a_lo < 360):
            raise ValueError(f"inplane_range_deg must be finite with low <= high and a span "
                             f"under 360, got {self.inplane_range_deg}")
        if self.vote_cell is not None and not self.vote_cell > 0:
            raise ValueError(f"vote_cell must be positive or None, got {self.vote_cell!r}")
        if self.clutter_sigma is not None and not self.clutter_sigma > 0:
            raise ValueError(f"clutter_sigma must be positive or None, got {self.clutter_sigma!r}")
        if not 0 <= self.coherence_floor < 1:
            raise ValueError(f"coherence_floor must be in [0, 1), got {self.coherence_floor!r}")
        if not self.crowding_limit >= 1:
            raise ValueError(f"crowding_limit must be >= 1, got {self.crowding_limit!r}")
        if self.refine_scale_steps is not None and not (
                isinstance(self.refine_scale_steps, (int, float))
                and np.isfinite(self.refine_scale_steps) and self.refine_scale_steps > 0):
            raise ValueError(f"refine_scale_steps must be positive or None, "
                             f"got {self.refine_scale_steps!r}")
        if self.density_cap is not None and not self.density_cap > 0:
            raise ValueError(f"density_cap must be positive or None, got {self.density_cap!r}")
        if not 0 <= self.contrast <= 1:
            raise ValueError(f"contrast must be in [0, 1], got {self.contrast!r}")
        if not 0 <= self.k1_cutoff < 1:
            raise ValueError(f"k1_cutoff must be in [0, 1), got {self.k1_cutoff!r}")
        if not (isinstance(self.verify_candidates, (int, np.integer))
                and self.verify_candidates >= 0):
            raise ValueError(f"verify_candidates must be an integer >= 0, "
                             f"got {self.verify_candidates!r}")
        if not (isinstance(self.verify_margin, (int, float)) and 0 <= self.verify_margin <= 2):
            raise ValueError(f"verify_margin must be in [0, 2], got {self.verify_margin!r}")
        if not (isinstance(self.verify_objectness_weight, (int, float))
                and np.isfinite(self.verify_objectness_weight)
                and self.verify_objectness_weight >= 0):
            raise ValueError(f"verify_objectness_weight must be a finite number >= 0, "
                             f"got {self.verify_objectness_weight!r}")
        if not (isinstance(self.appearance_jitter, (int, float))
                and 0 <= self.appearance_jitter < 0.5):
            raise ValueError(f"appearance_jitter must be in [0, 0.5), "
                             f"got {self.appearance_jitter!r}")
        if not (isinstance(self.verify_overlap, (int, float)) and 0 <= self.verify_overlap < 1):
            raise ValueError(f"verify_overlap must be in [0, 1), got {self.verify_overlap!r}")
        self._pruning()
        if not self.instance_margin >= 1:
            raise ValueError(f"instance_margin must be >= 1, got {self.instance_margin!r}")
        if self.viewpoint_step_deg is not None and not self.viewpoint_step_deg > 0:
            raise ValueError(f"viewpoint_step_deg must be positive or None, "
                             f"got {self.viewpoint_step_deg!r}")
        if self.verify_tolerance_deg is not None and not (
                isinstance(self.verify_tolerance_deg, (int, float))
                and 0 < self.verify_tolerance_deg <= 180):
            raise ValueError(f"verify_tolerance_deg must be in (0, 180] or None, "
                             f"got {self.verify_tolerance_deg!r}")
        if self.viewpoint_bandwidth_deg is not None and not self.viewpoint_bandwidth_deg > 0:
            raise ValueError(f"viewpoint_bandwidth_deg must be positive or None, "
                             f"got {self.viewpoint_bandwidth_deg!r}")

    # -- training ---------------------------------------------------------------
    def _edges(self, image: NDArray[np.float64], *, mask: NDArray[np.bool_] | None,
               max_points: int | None) -> EdgeFeatures:
        low, high = self.edge_thresholds
        return detect_edges(image, sigma=self.edge_sigma, low_threshold=low, high_threshold=high,
                            spacing=self.edge_spacing, max_points=max_points, mask=mask)

    def fit(
        self,
        images: Sequence[ImageLike],
        poses: ArrayLike,
        *,
        boxes: ArrayLike | None = None,
        masks: Sequence[ImageLike | None] | None = None,
        instances: Sequence[str] | None = None,
        category: str = "",
        progress: Callable[[int], None] | None = None,
    ) -> PoseEstimator:
        """Learn the model from pose-annotated images (Sec. II-A, II-C).

        Parameters
        ----------
        images : sequence of (path or ndarray)
            Training images (grey, RGB, RGBA; 8-bit, 16-bit or float).
        poses : array_like, shape (K,), (K, 2) or (K, 3)
            Azimuth, optionally elevation and in-plane angle, radians.
        boxes : array_like, shape (K, 4), optional
            Object boxes ``(x, y, w, h)`` in pixels; NaN rows or None use the
            mask's box, else the whole image.
        masks : sequence of (path, ndarray or None), optional
            Object masks; edges are kept only inside (grown by 2 pixels).
        instances : sequence of str, optional
            Instance name of each image (one instance if None).
        category : str, optional
            Category name to record.
        progress : callable, optional
            Called with 1 after each image is processed.

        Returns
        -------
        self

        Raises
        ------
        ValueError
            On inconsistent lengths, non-finite poses, boxes outside their
            image, or a training image without edges.
        """
        self._validate_params()
        images = list(images)
        k = len(images)
        if k == 0:
            raise ValueError("images: need at least one training image")
        pose_arr = np.asarray(poses, dtype=np.float64)
        if pose_arr.ndim == 1:
            pose_arr = pose_arr[:, None]
        if pose_arr.ndim != 2 or pose_arr.shape[0] != k or not 1 <= pose_arr.shape[1] <= 3:
            raise ValueError(f"poses must have shape ({k},), ({k}, 2) or ({k}, 3) for {k} images, "
                             f"got {np.shape(poses)}")
        if not np.all(np.isfinite(pose_arr)):
            row = int(np.flatnonzero(~np.all(np.isfinite(pose_arr), axis=1))[0])
            raise ValueError(f"poses: row {row} is not finite ({pose_arr[row].tolist()})")
        pose_arr = np.hstack([pose_arr, np.zeros((k, 3 - pose_arr.shape[1]))])
        box_arr = (np.full((k, 4), np.nan) if boxes is None
                   else np.asarray(boxes, dtype=np.float64).reshape(-1, 4))
        if box_arr.shape[0] != k:
            raise ValueError(f"boxes must have {k} rows, got {box_arr.shape[0]}")
        mask_list = list(masks) if masks is not None else [None] * k
        if len(mask_list) != k:
            raise ValueError(f"masks must have {k} entries, got {len(mask_list)}")
        names = list(instances) if instances is not None else ["object"] * k
        if len(names) != k:
            raise ValueError(f"instances must have {k} entries, got {len(names)}")

        feats, centres, sizes = [], np.zeros((k, 2)), np.zeros((k, 2))
        appearance = _Appearance(box_arr, regression=self.appearance_refine)
        crops = ViewCrops() if self.morph_views else None
        for i, image in enumerate(images):
            label = str(image) if isinstance(image, (str, Path)) else f"images[{i}]"
            img = _load(image, name=label)
            mask = mask_list[i]
            if mask is not None and not isinstance(mask, np.ndarray):
                mask = read_mask(mask)
            if mask is not None:
                mask = np.asarray(mask, dtype=bool)
                if mask.shape != img.shape:
                    raise ValueError(f"{label}: mask shape {mask.shape} differs from image "
                                     f"shape {img.shape}")
                if not mask.any():
                    raise ValueError(f"{label}: the mask is empty")
            box = box_arr[i]
            if np.all(np.isnan(box)):
                if mask is not None:
                    rows, cols = np.nonzero(mask)
                    box = np.array([cols.min(), rows.min(), np.ptp(cols) + 1, np.ptp(rows) + 1],
                                   dtype=float)
                else:
                    box = np.array([0.0, 0.0, img.shape[1], img.shape[0]])
            elif not np.all(np.isfinite(box)):
                raise ValueError(f"{label}: box {box.tolist()} has NaN values")
            x, y, w, h = box
            if w <= 0 or h <= 0 or x < -0.5 or y < -0.5 or x + w > img.shape[1] + 0.5 \
                    or y + h > img.shape[0] + 0.5:
                raise ValueError(f"{label}: box (x={x:g}, y={y:g}, w={w:g}, h={h:g}) is not inside "
                                 f"the {img.shape[1]}x{img.shape[0]} image")
            region = box_mask(img.shape, box)
            if mask is not None:
                region &= binary_dilation(mask, iterations=2)
            f = self._edges(img, mask=region, max_points=self.max_train_features)
            if len(f) == 0:
                raise ValueError(f"{label}: no edges found on the object; check the box/mask "
                                 "or lower edge_thresholds")
            feats.append(f)
            appearance.add(img, box, float(pose_arr[i, 0]))
            if crops is not None:
                crops.add(img, box)
            centres[i] = box_centre(box)
            sizes[i] = [w, h]
            if progress is not None:
                progress(1)

        instance_names = sorted(set(names))
        inst_index = np.array([instance_names.index(n) for n in names])
        # Each instance keeps its own typical size; instances are brought to
        # the common reference size (the median of their median box heights).
        inst_height = np.array([np.median(sizes[inst_index == j, 1])
                                for j in range(len(instance_names))])
        reference = float(np.median(inst_height))
        inst_size = inst_height / reference
        scales = inst_size[inst_index]
        model = build_model(feats, poses=pose_arr, centers=centres, scales=scales,
                            box_sizes=sizes, instances=inst_index, instance_names=instance_names,
                            reference_size=reference, category=category,
                            instance_size=inst_size.tolist())
        if crops is not None:
            neighbours = turntable_neighbours(model.view_azimuth, model.view_elevation,
                                              model.view_instance)
            model = replace(model, view_neighbour=neighbours, shift=view_shifts(
                feats, crops, neighbours, centers=centres, scales=scales,
                inplanes=pose_arr[:, 2]))
        self.viewpoint_kappa_ = self._viewpoint_kappa(model)
        (self.descriptor_window_, self.view_descriptors_, self.objectness_,
         self.box_regressor_) = appearance.finish(sizes)
        weights = feature_weights(model, position_sigma=self.position_sigma,
                                  orientation_kappa=self.orientation_kappa,
                                  viewpoint_kappa=self.viewpoint_kappa_)
        self.full_model_ = model.with_weights(weights)
        preset = self._pruning()
        self.model_ = self.full_model_ if preset is None else prune_model(
            self.full_model_, preset, position_sigma=self.position_sigma,
            orientation_kappa=self.orientation_kappa)
        self.pruning_ = None if preset is None else asdict(preset)
        return self

    def _pruning(self) -> PruningPreset | None:
        """The pruning knobs asked for, or None (raises ValueError on bad ones)."""
        overrides = (self.prune_pose_std_deg, self.prune_appearance_std)
        preset = resolve_preset(self.prune if self.prune is not None or overrides == (None, None)
                                else "moderate")
        if preset is None:
            return None
        return resolve_preset(PruningPreset(
            pose_std_deg=float(overrides[0] if overrides[0] is not None else preset.pose_std_deg),
            appearance_std=float(overrides[1] if overrides[1] is not None
                                 else preset.appearance_std)))

    def _viewpoint_kappa(self, model: PoseModel) -> float:
        if self.viewpoint_bandwidth_deg is not None:
            return kappa_for_width(np.radians(self.viewpoint_bandwidth_deg))
        d = model.view_directions()
        d = np.unique(np.round(d, 9), axis=0)
        if len(d) < 2:
            return kappa_for_width(np.radians(10.0))
        cosines = np.clip(d @ d.T, -1.0, 1.0)
        np.fill_diagonal(cosines, -1.0)
        spacing = float(np.median(np.arccos(cosines.max(axis=1))))
        # Morphed features move with the object, so a wider kernel blends
        # neighbours without blurring them (docs/TUNING.md, "Morphing").
        return kappa_for_width(spacing * (MORPH_BANDWIDTH if model.shift is not None else 0.5))

    def _check_fitted(self) -> PoseModel:
        model = getattr(self, "model_", None)
        if model is None:
            raise NotFittedError("this PoseEstimator is not fitted yet; call fit() or load() first")
        return model

    # -- estimation ---------------------------------------------------------------
    def search_grid(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The in-plane angles (radians) and scales searched."""
        a_lo, a_hi = np.radians(self.inplane_range_deg)
        step = np.radians(self.inplane_step_deg)
        n_a = int(np.floor((a_hi - a_lo) / step + 1e-9)) + 1
        inplanes = (a_lo + a_hi) / 2.0 + (np.arange(n_a) - (n_a - 1) / 2.0) * step
        lo, hi = self.scale_range
        scales = np.geomspace(lo, hi, self.scale_steps) if self.scale_steps > 1 \
            else np.array([np.sqrt(lo * hi)])
        return inplanes, scales

    def search_sigma(self, inplanes: NDArray[np.float64], scales: NDArray[np.float64]) -> float:
        """Position kernel width used while searching, pixels.

        A probe lies up to half a grid step from the true in-plane angle and
        scale; a feature at radius ``r`` is then displaced by about
        ``r * step / 2``. The kernel is widened by that amount (in
        quadrature) so that the probe nearest the truth keeps its score,
        instead of losing it to clutter between grid steps.
        """
        model = self._check_fitted()
        r = float(np.sqrt(np.mean(np.sum(model.xy**2, axis=1)))) * float(np.max(scales))
        d_alpha = float(np.median(np.diff(inplanes))) if len(inplanes) > 1 else 0.0
        d_log_s = float(np.median(np.diff(np.log(scales)))) if len(scales) > 1 else 0.0
        return float(np.sqrt(self.position_sigma**2 + (r * d_alpha / 2.0) ** 2
                             + (r * d_log_s / 2.0) ** 2))

    def _features(self, image: ImageLike) -> tuple[EdgeFeatures, tuple[int, int]]:
        return self._read(image)[:2]

    def _read(self, image: ImageLike
              ) -> tuple[EdgeFeatures, tuple[int, int], NDArray[np.float64]]:
        """The test image's features, shape and grey pixels."""
        img = _load(image, name=str(image) if isinstance(image, (str, Path)) else "image")
        feats = self._edges(img, mask=None, max_points=self.max_test_features)
        return feats, (int(img.shape[0]), int(img.shape[1])), img

    def _maps(self, feats: EdgeFeatures, shape: tuple[int, int], *, sigma: float,
              scale: float = 1.0, search: bool = False) -> TestMaps:
        """Test maps at kernel width ``sigma``; ``density_cap`` applies to the search's only.

        The cap was chosen for the coarse search in clutter; the narrow maps
        of the local and instance refinements keep the unsaturated density,
        whose ridges give the precise alignment.
        """
        return prepare_test(feats, shape, position_sigma=sigma,
                            orientation_kappa=self.orientation_kappa,
                            edge_spacing=self.edge_spacing / scale, clutter_sigma=self.clutter_sigma,
                            coherence_floor=self.coherence_floor,
                            crowding_limit=self.crowding_limit,
                            density_cap=self.density_cap if search else None,
                            contrast=self.contrast)

    def _search_maps(self, feats: EdgeFeatures, shape: tuple[int, int]
                     ) -> TestMaps | list[TestMaps]:
        """The test maps the search runs on: one set, or one per scale (``object_kernel``)."""
        inplanes, scales = self.search_grid()
        sigma = self.search_sigma(inplanes, scales)
        if not self.object_kernel:
            return self._maps(feats, shape, sigma=sigma, search=True)
        return [self._maps(*scaled_features(feats, shape, float(s)), sigma=sigma, scale=float(s),
                           search=True) for s in scales]

    def _probe(self, maps: TestMaps | list[TestMaps], progress: Callable[[int], None] | None,
               *, model: PoseModel | None = None, near: Hypothesis | None = None,
               size: float = 1.0) -> ProbeSet:
        """Probe p(w) on the grid; with ``near``, only viewpoints within 3 steps of it.

        ``size`` multiplies the scale grid (an instance's training size);
        per-scale maps fix the grid, and then it is ignored.
        """
        model = self._check_fitted() if model is None else model
        step = None if self.viewpoint_step_deg is None else np.radians(self.viewpoint_step_deg)
        az, el = viewpoint_grid(model, subdivisions=self.viewpoint_subdivisions, step=step)
        if near is not None and len(az) > 3:
            dirs = viewing_direction(az, el)
            cosines = dirs @ viewing_direction(near.azimuth, near.elevation)
            gap = float(np.median(np.diff(np.sort(az)))) if np.ptp(el) < 1e-9 else np.radians(20)
            keep = cosines >= np.cos(3.0 * gap)
            if keep.sum() < 3:
                keep = np.isin(np.arange(len(az)), np.argsort(-cosines)[:3])
            az, el = az[keep], el[keep]
        inplanes, scales = self.search_grid()
        if isinstance(maps, TestMaps):
            scales = scales * size
        return probe_poses(model, maps, azimuths=az, elevations=el, inplanes=inplanes,
                           scales=scales, viewpoint_kappa=self.viewpoint_kappa_,
                           use_weights=self.weights, k1_cutoff=self.k1_cutoff,
                           cell=self.vote_cell, max_voters=self.max_voters,
                           max_features=self.max_search_features,
                           n_candidates=self.vote_candidates,
                           chance_correction=self.chance_correction, progress=progress,
                           n_threads=self.n_jobs)

    def probe(self, image: ImageLike, *, progress: Callable[[int], None] | None = None
              ) -> tuple[ProbeSet, EdgeFeatures]:
        """The probes of p(w) for an image (Fig. 2), before refinement.

        Parameters
        ----------
        image : path or ndarray
            The test image.
        progress : callable, optional
            Called with 1 after each probed viewpoint.

        Returns
        -------
        probes : ProbeSet
        features : EdgeFeatures
            The test image's edge features.
        """
        self._check_fitted()
        self._validate_params()
        feats, shape = self._features(image)
        return self._probe(self._search_maps(feats, shape), progress), feats

    def estimate(self, image: ImageLike) -> PoseEstimate:
        """Find the object and estimate its continuous pose (Sec. II-B).

        Parameters
        ----------
        image : path or ndarray
            The test image: grey, RGB or RGBA; 8-bit, 16-bit or float.

        Returns
        -------
        PoseEstimate
            ``found`` is False when the image has no edges or no mode scores
            above ``min_score``.
        """
        start = time.perf_counter()
        self._check_fitted()
        self._validate_params()
        feats, shape, img = self._read(image)
        search_maps = self._search_maps(feats, shape)
        probes = self._probe(search_maps, None)
        verified_box: tuple[float, ...] | None = None
        if self.verify_candidates and probes.score.any():
            located = self._verify(probes, img, feats, search_maps)
            if located is not None:
                feats, search_maps, probes, verified_box = located
        modes = find_modes(probes, max_modes=self.max_modes)
        hyps = [refine_mode(probes, v, fit=self.fitting, radius_steps=self.fit_radius_steps,
                            view_shape=self.fit_view_shape) for v in modes]
        fine = self._maps(feats, shape, sigma=self.position_sigma) \
            if hyps and (self.local_refinement or self._recognizing()) else None
        if self.local_refinement and hyps and fine is not None:
            # The best ``refine_modes`` modes (one by default) are polished
            # and ranked again by their narrow scores; the others are
            # reported as alternatives, and their fitted pose is enough.
            scale_maps = None
            if self.narrow_scale and self.object_kernel and self.fitting:
                scale_maps = [self._maps(*scaled_features(feats, shape, float(s)),
                                         sigma=self.position_sigma, scale=float(s))
                              for s in self.search_grid()[1]]
            hyps = rank_refined(hyps, lambda k, h: self._local(probes, modes[k], h, self.model_,
                                                               fine, scale_maps),
                                self.refine_modes)
        instance, margin = "", float("nan")
        if self._recognizing() and hyps and fine is not None:
            hyps, instance, margin = self._recognize(hyps, feats, search_maps, fine)
        if self.appearance_refine and hyps:
            hyps = [self._appearance(hyps[0], img, verified_box)] + hyps[1:]
        kept = tuple(h for h in hyps if h.score > self.min_score)
        return PoseEstimate(found=bool(kept), best=kept[0] if kept else None, modes=kept,
                            n_test_features=len(feats), seconds=time.perf_counter() - start,
                            instance=instance if kept else "", instance_margin=margin)

    def _appearance(self, hyp: Hypothesis, image: NDArray[np.float64],
                    verified_box: tuple[float, ...] | None = None) -> Hypothesis:
        """The best mode in its regressed box, its viewpoint the nearest view's (``appearance_refine``).

        The box is the verification winner's regressed box when there is one
        (``verified_box``; the appearance chose it among the candidates),
        else the mode's own box, regressed.
        """
        regressor = self._box_regressor()
        if regressor is None:
            return hyp
        descriptors = self.view_descriptors_
        window = self.descriptor_window_
        if verified_box is not None:
            vx, vy, vw, vh = verified_box
            box, d = (vx, vy, vw, vh), box_descriptor(image, verified_box, window)
        else:
            box, d = regress_described(image, hyp.box, box_descriptor(image, hyp.box, window),
                                       regressor, hyp.azimuth, window=window)
        out = replace(hyp, box=box, position=box_centre(box),
                      scale=hyp.scale * box[3] / hyp.box[3] if hyp.box[3] > 0 else hyp.scale)
        if d is None:
            return out
        model = self._check_fitted()
        direction = viewing_direction(hyp.azimuth, hyp.elevation)
        if self.appearance_jitter > 0:
            k = jittered_nearest_view(image, box, descriptors, model.view_directions(), direction,
                                      window=np.radians(self.appearance_window_deg),
                                      descriptor_window=window, fraction=self.appearance_jitter)
        else:
            k = nearest_view(d, descriptors, model.view_directions(), direction,
                             window=np.radians(self.appearance_window_deg))
        if k is None:
            return out
        return replace(out, azimuth=float(model.view_azimuth[k]),
                       elevation=float(model.view_elevation[k]))

    def _recognize(self, hyps: list[Hypothesis], feats: EdgeFeatures,
                   search_maps: TestMaps | list[TestMaps], fine: TestMaps
                   ) -> tuple[list[Hypothesis], str, float]:
        """Recognise the instance and re-estimate with its model (Sec. III-B).

        Returns the modes (the instance's estimate first when one wins by
        ``instance_margin``), the instance's name ("" if none) and the
        recognition margin.
        """
        names = self.full_model_.instance_names
        if self.instance_search:
            own = [self._instance_refine(i, hyps[0], search_maps, fine, near=False)
                   for i in range(len(names))]
            # Each instance is judged at its own estimate. (Judging it at the
            # better aligned of its own estimate and the category's lost on
            # the category cross-validation, docs/TUNING.md.)
            best, margin = recognition_margin(self._explained(own, feats, fine))
            if margin < self.instance_margin:
                return hyps, "", margin
            # The category mode nearest to the instance's estimate gives way to it.
            at = int(np.argmin([angular_error(h.azimuth, own[best].azimuth) for h in hyps]))
            refined = own[best]
        else:
            per_mode = np.array([self.instance_scores(h, feats, fine)
                                 for h in hyps[:self.recognition_modes]])
            best, margin = recognition_margin(per_mode.max(axis=0))
            if margin < self.instance_margin:
                return hyps, "", margin
            at = int(np.argmax(per_mode[:, best]))
            refined = self._instance_refine(best, hyps[at], search_maps, fine)
        return [refined] + [h for k, h in enumerate(hyps) if k != at], names[best], margin

    def _verify(self, probes: ProbeSet, image: NDArray[np.float64], feats: EdgeFeatures,
                search_maps: TestMaps | list[TestMaps]
                ) -> tuple[EdgeFeatures, TestMaps | list[TestMaps], ProbeSet,
                           tuple[float, ...] | None] | None:
        """Verify the best probes by appearance and search again in the winner's box.

        Returns the test features inside the verified box (grown by
        ``verify_margin``), the search maps restricted to it, the probes
        near the verified viewpoint and, with ``appearance_refine``, the
        winner's regressed box (else None); or None when no candidate could
        be verified.
        """
        descriptors = getattr(self, "view_descriptors_", None)
        if descriptors is None:
            raise ValueError("verify_candidates needs the training views' appearance "
                             "descriptors, which this model lacks (written by an older "
                             "posevote); retrain it")
        model = self._check_fitted()
        regressor = self._box_regressor()
        found = verify_candidates(probes, image, descriptors, model.view_azimuth,
                                  model.view_elevation, window=self.descriptor_window_,
                                  n_candidates=self.verify_candidates,
                                  tolerance=probe_spacing(probes)
                                  if self.verify_tolerance_deg is None
                                  else np.radians(self.verify_tolerance_deg),
                                  objectness=getattr(self, "objectness_", None),
                                  shortlist=self.verify_shortlist,
                                  regressor=regressor,
                                  objectness_weight=self.verify_objectness_weight)
        if found is None:
            return None
        (v, a, s), _, box = found
        size = probes.box[v] * probes.scale[s]
        centre = probes.translation[v, a, s]
        if regressor is not None:
            # The winner was judged on its regressed box: search again inside that.
            size = np.array(box[2:])
            centre = np.asarray(box_centre(box), dtype=np.float64)
        half = size * (0.5 + self.verify_margin)
        keep = np.all(np.abs(feats.xy - centre) <= half, axis=1)
        if not keep.any():
            return None
        if isinstance(search_maps, TestMaps):
            maps: TestMaps | list[TestMaps] = restrict_maps(search_maps, centre - half,
                                                            centre + half)
        else:
            maps = [restrict_maps(m, (centre - half) / f, (centre + half) / f)
                    for m, f in zip(search_maps, probes.scale, strict=True)]
        x, y, w, h = box
        near = Hypothesis(azimuth=float(probes.azimuth[v]), elevation=float(probes.elevation[v]),
                          inplane=float(probes.inplane[a]), scale=float(probes.scale[s]),
                          position=(float(centre[0]), float(centre[1])), box=(x, y, w, h),
                          score=float(probes.score[v, a, s]), refined=False)
        again = self._probe(maps, None, near=near)
        if self.verify_overlap > 0:
            # The edges inside the grown box still fit a part of the object at
            # a smaller scale; the appearance chose this box, so stay near it.
            again = replace(again, score=np.where(
                box_iou(again.boxes(), near.box) >= self.verify_overlap, again.score, 0.0))
        return feats.select(keep), maps, again, box if regressor is not None else None

    def _box_regressor(self) -> NDArray[np.float64] | None:
        """The box regressions with ``appearance_refine`` (None without it)."""
        if not self.appearance_refine:
            return None
        regressor = getattr(self, "box_regressor_", None)
        if regressor is None or getattr(self, "view_descriptors_", None) is None:
            raise ValueError("appearance_refine needs the box regression learned when the model "
                             "is fitted; fit (or retrain) with appearance_refine=True")
        return regressor

    def _recognizing(self) -> bool:
        return bool(self.recognize_instance) and len(self._check_fitted().instance_names) > 1

    def _local(self, probes: ProbeSet, viewpoint: int, hyp: Hypothesis, model: PoseModel,
               fine: TestMaps, scale_maps: list[TestMaps] | None = None) -> Hypothesis:
        """The local refinement of one mode (``local_refinement``).

        With ``scale_maps`` (one narrow set per search scale, object units),
        the mode's scale is first chosen again (``narrow_scale``).
        """
        kw: dict[str, Any] = {"viewpoint_kappa": self.viewpoint_kappa_,
                              "use_weights": self.weights, "k1_cutoff": self.k1_cutoff}
        if self.fitting:
            margin = None
            if self.refine_scale_steps is not None:
                # The grid's log-scale step, as in search_sigma (0 for one scale).
                _, scales = self.search_grid()
                step = float(np.median(np.diff(np.log(scales)))) if len(scales) > 1 else 0.0
                margin = self.refine_scale_steps * max(step, 0.05)
            if scale_maps is not None and (
                    chosen := rescale_anchor(probes, viewpoint, model, scale_maps, **kw)):
                anchor, s = chosen
                return profile_refine(probes, viewpoint, model, scale_maps[s],
                                      scale_margin=margin, radius_steps=self.fit_radius_steps,
                                      view_shape=self.fit_view_shape, anchor=anchor,
                                      frame_scale=float(probes.scale[s]),
                                      interpolate=self.interpolate_alignment, **kw)
            return profile_refine(probes, viewpoint, model, fine, scale_margin=margin,
                                  radius_steps=self.fit_radius_steps,
                                  view_shape=self.fit_view_shape,
                                  interpolate=self.interpolate_alignment, **kw)
        return polish_pose(hyp, model, fine, **kw)

    def instance_scores(self, hypothesis: Hypothesis, features: EdgeFeatures,
                        maps: TestMaps) -> NDArray[np.float64]:
        """Score of each trained instance at a pose (Eqs. 5-6).

        Each instance's own (full, unpruned) model is first aligned to the
        image from ``w*`` (in-plane angle, scale and translation polished
        on the exact p(w), since instances differ in shape), then scored by
        the fraction of the test features in its box that it explains
        (:func:`posevote.inference.recognition.explained_fraction`).

        Parameters
        ----------
        hypothesis : Hypothesis
            The category estimate ``w*``.
        features : EdgeFeatures
            The test image's features.
        maps : TestMaps
            The test image tabulated with the narrow kernel.

        Returns
        -------
        ndarray, shape (n_instances,)
        """
        return self._explained([hypothesis] * len(self.full_model_.instance_names), features,
                               maps)

    def _explained(self, hypotheses: Sequence[Hypothesis], features: EdgeFeatures,
                   maps: TestMaps) -> NDArray[np.float64]:
        """Each instance's explained fraction, aligned from its own hypothesis."""
        full = self.full_model_
        kw: dict[str, Any] = {"viewpoint_kappa": self.viewpoint_kappa_,
                              "use_weights": self.weights, "k1_cutoff": self.k1_cutoff}
        subs = [full.instance_model(i) for i in range(len(full.instance_names))]
        aligned = [polish_pose(h, sub, maps, **kw) for h, sub in zip(hypotheses, subs, strict=True)]
        # All instances are judged on the same test features: those in the
        # union of their boxes.
        corners = np.array([[h.box[0], h.box[1], h.box[0] + h.box[2], h.box[1] + h.box[3]]
                            for h in aligned])
        lo, hi = corners[:, :2].min(axis=0), corners[:, 2:].max(axis=0)
        box = (float(lo[0]), float(lo[1]), float(hi[0] - lo[0]), float(hi[1] - lo[1]))
        return np.array([
            explained_fraction(features, sub, h, box=box, position_sigma=self.position_sigma,
                               orientation_kappa=self.orientation_kappa, **kw)
            for sub, h in zip(subs, aligned, strict=True)])

    def _instance_refine(self, instance: int, hyp: Hypothesis,
                         search_maps: TestMaps | list[TestMaps], fine: TestMaps, *,
                         near: bool = True) -> Hypothesis:
        """Re-estimate near ``hyp`` with one instance's full model (Sec. III-B).

        With ``near=False`` the instance searches every viewpoint, on the
        scale grid centred on its training size (``instance_search``).
        """
        model = self.full_model_.instance_model(instance)
        probes = self._probe(search_maps, None, model=model, near=hyp) if near else \
            self._probe(search_maps, None, model=model, size=self.full_model_.size_of(instance))
        if not probes.score.any():
            return hyp
        v = int(np.argmax(probes.score.max(axis=(1, 2))))
        refined = refine_mode(probes, v, fit=self.fitting, radius_steps=self.fit_radius_steps,
                              view_shape=self.fit_view_shape)
        if self.local_refinement:
            refined = self._local(probes, v, refined, model, fine)
        return refined

    # -- persistence -----------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write the fitted model to a file (atomically); see :mod:`posevote.model.modelfile`."""
        model = self._check_fitted()
        full = getattr(self, "full_model_", model)
        save_model(path, model, self.get_params(),
                   extra={"viewpoint_kappa": self.viewpoint_kappa_,
                          "pruning": getattr(self, "pruning_", None),
                          "descriptor_window": list(getattr(self, "descriptor_window_", ()))},
                   full_model=None if full is model else full,
                   descriptors=getattr(self, "view_descriptors_", None),
                   objectness=getattr(self, "objectness_", None),
                   box_regressor=getattr(self, "box_regressor_", None))

    @classmethod
    def load(cls, path: str | Path) -> PoseEstimator:
        """Read an estimator written by :meth:`save`.

        Raises
        ------
        FileNotFoundError, ValueError
            Missing, foreign, corrupt or too-new files (message names the file).
        """
        model, params, extra, full, descriptors, objectness, regressor = load_model(path)
        est = cls()
        try:
            est.set_params(**params)
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None
        est.model_ = model
        est.full_model_ = model if full is None else full
        est.viewpoint_kappa_ = float(extra.get("viewpoint_kappa", est._viewpoint_kappa(model)))
        est.pruning_ = extra.get("pruning")
        window = extra.get("descriptor_window")
        if descriptors is not None and isinstance(window, list) and len(window) == 2:
            est.descriptor_window_ = (int(window[0]), int(window[1]))
            if descriptors.shape[1] != descriptor_length(est.descriptor_window_):
                raise ValueError(f"{path}: corrupt model file (view_descriptor length "
                                 f"{descriptors.shape[1]} does not fit window {window})")
            est.view_descriptors_ = descriptors
            if objectness is not None and objectness.shape != (descriptors.shape[1] + 1,):
                raise ValueError(f"{path}: corrupt model file (objectness has shape "
                                 f"{objectness.shape})")
            est.objectness_ = objectness
            if regressor is not None and regressor.shape[1:] != (4, descriptors.shape[1] + 1):
                raise ValueError(f"{path}: corrupt model file (box_regressor has shape "
                                 f"{regressor.shape})")
            est.box_regressor_ = regressor
        return est
