"""The estimator: training (Sec. II-A, II-C) and estimation (Sec. II-B) in one object.

:class:`PoseEstimator` only orchestrates: every stage is a plain function of
its subpackage (``features`` -> ``model`` -> ``inference`` -> ``refinement``),
and every stage's settings are one frozen option group that validates itself.
Named, tuned configurations are :mod:`posevote.presets`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from posevote._errors import not_fitted_error
from posevote._options import GroupedParams, Options, params_from_json, params_to_json
from posevote.camera import Camera, place_all
from posevote.data.images import load_image
from posevote.features.edges import EdgeFeatures, EdgeOptions, extract_edges, without_box
from posevote.geometry import box_iou, rotate_points
from posevote.inference.coverage import rerank_by_coverage
from posevote.inference.maps import TestMaps
from posevote.inference.search import (
    OBJECT_MARGIN,
    OBJECT_OVERLAP,
    ProbeSet,
    SearchOptions,
    SearchSetup,
    image_maps,
    probe,
    search_maps,
)
from posevote.inference.templates import gradient_similarity, pose_correlations, rerank_by_template
from posevote.inference.verification import verify
from posevote.model.appearance import AppearanceModel, AppearanceOptions
from posevote.model.density import PoseModel, origin_offset
from posevote.model.kernels import K1_CUTOFF, KernelOptions
from posevote.model.outline import outline_at, outline_box
from posevote.model.pruning import PruningPreset, resolve_preset
from posevote.model.training import TrainedModel, extend_model, train_model
from posevote.presets import get_preset, nearest_preset
from posevote.refinement.appearance import appearance_refine
from posevote.refinement.fitting import FIT_RADIUS_STEPS, find_modes, refine_mode
from posevote.refinement.halfturn import half_turn
from posevote.refinement.instance import RecognitionOptions, recognize
from posevote.refinement.local import local_refine, rescale_mode
from posevote.refinement.probability import scored_viewpoints, with_probabilities
from posevote.refinement.share import share_scale
from posevote.results import Hypothesis, PoseEstimate

ImageLike = str | Path | NDArray

#: The option group of each grouped parameter (None switches a stage off).
OPTION_GROUPS: dict[str, type[Options]] = {
    "edges": EdgeOptions, "kernel": KernelOptions, "search": SearchOptions,
    "recognition": RecognitionOptions, "appearance": AppearanceOptions}


class PoseEstimator(GroupedParams):
    """Continuous 3D pose of an object in a single image (Teney & Piater 2013).

    Build one from a named preset (:meth:`from_preset`, :mod:`posevote.presets`)
    rather than by hand; every parameter can be overridden there.

    Parameters
    ----------
    weights : bool, default True
        Weight training features by pose specificity (Eq. 4).
    fitting : bool, default True
        Refine each mode by local distribution fitting (Sec. II-B).
    local_refinement : bool, default False
        Maximise the exact p(w) of the best mode with the narrow kernel over
        in-plane angle, scale and translation at the viewpoints near it, and
        fit the viewpoint to those maxima (beyond the paper;
        :func:`posevote.refinement.local.local_refine`).
    morph_views : bool, default False
        Training: measure by optical flow where each feature moves to in the
        neighbouring views (in azimuth; over a sphere of views also in
        elevation), so that features between training views move with the
        object (beyond the paper; :mod:`posevote.model.morph`). Probe the
        gaps too (``SearchOptions(viewpoint_subdivisions=2)``).
    edges : EdgeOptions
        Edge extraction (:class:`posevote.features.edges.EdgeOptions`).
    kernel : KernelOptions
        Kernel widths (:class:`posevote.model.kernels.KernelOptions`).
    search : SearchOptions
        The search grid and scoring (:class:`posevote.inference.search.SearchOptions`).
    prune : {None, "moderate", "aggressive"} or PruningPreset, default None
        Prune a pooled model by clustering (Sec. III-A); the search then runs
        on the cluster centres, recognition and refinement on the full model.
    recognition : RecognitionOptions or None
        Instance recognition for models of several instances (Sec. III-B;
        :class:`posevote.refinement.instance.RecognitionOptions`); None: off.
    appearance : AppearanceOptions or None, default None
        HOG verification, box regression and nearest-view viewpoint (beyond
        the paper; :class:`posevote.model.appearance.AppearanceOptions`);
        learnt when the model is fitted. None: off.
    max_modes : int, default 3
        Modes reported per image.
    min_score : float, default 0.0
        Below this best score the estimate is "not found".
    n_jobs : int, default 1
        Threads probing viewpoints (and reading training images) at once:
        the time of an estimate or of training, not its result.
    """

    _groups = OPTION_GROUPS

    def __init__(self, *, weights: bool = True, fitting: bool = True,
                 local_refinement: bool = False, morph_views: bool = False,
                 edges: EdgeOptions = EdgeOptions(), kernel: KernelOptions = KernelOptions(),
                 search: SearchOptions = SearchOptions(),
                 prune: str | PruningPreset | None = None,
                 recognition: RecognitionOptions | None = RecognitionOptions(),
                 appearance: AppearanceOptions | None = None, max_modes: int = 3,
                 min_score: float = 0.0, n_jobs: int = 1) -> None:
        self.weights, self.fitting = weights, fitting
        self.local_refinement, self.morph_views = local_refinement, morph_views
        self.edges, self.kernel, self.search = edges, kernel, search
        self.prune, self.recognition, self.appearance = prune, recognition, appearance
        self.max_modes = max_modes
        self.min_score = min_score
        self.n_jobs = n_jobs

    @classmethod
    def from_preset(cls, name: str, **overrides: Any) -> PoseEstimator:
        """An estimator with the settings of preset ``name``, then ``overrides``.

        ``overrides`` are :meth:`set_params` keys: ``search=SearchOptions(...)``
        replaces a group, ``search__scale_steps=5`` one of its fields.
        """
        return cls(**get_preset(name).params).set_params(**overrides)

    def _validate_params(self) -> None:
        for name in ("weights", "fitting", "local_refinement", "morph_views"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
        for name, cls in OPTION_GROUPS.items():
            value = getattr(self, name)
            optional = name in ("recognition", "appearance")
            if not (isinstance(value, cls) or (optional and value is None)):
                raise TypeError(f"{name} must be a {cls.__name__}"
                                f"{' or None' if optional else ''}, got {value!r}")
        for name, high in (("max_modes", 100), ("n_jobs", 256)):
            value = getattr(self, name)
            if not (isinstance(value, (int, np.integer)) and not isinstance(value, bool)
                    and 1 <= value <= high):
                raise ValueError(f"{name} must be an integer in [1, {high}], got {value!r}")
        if not (isinstance(self.min_score, (int, float)) and np.isfinite(self.min_score)):
            raise ValueError(f"min_score must be a finite number, got {self.min_score!r}")
        resolve_preset(self.prune)

    # -- training ----------------------------------------------------------------------
    def fit(self, images: Sequence[ImageLike], poses: ArrayLike, *,
            boxes: ArrayLike | None = None, masks: Sequence[ImageLike | None] | None = None,
            instances: Sequence[str] | None = None, category: str = "",
            progress: Callable[[int], None] | None = None, channels: str = "rgb",
            object_height_m: float | None = None,
            origins: ArrayLike | None = None) -> PoseEstimator:
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
        channels : {"rgb", "bgr"}, optional
            Colour order of array images (``"bgr"``: from ``cv2.imread``).
        object_height_m : float, optional
            The object's height in metres (its box height), so that a camera
            can place it in depth (:mod:`posevote.camera`).
        origins : array_like, shape (K, 2) or (K, 3), optional
            The image ``(u, v)`` of the object's origin in each training image
            (a mesh origin projected with the training camera): ``t_cam_obj``
            then names that point instead of the box centre. A third column is
            the origin's depth over the depth this model gives the view at
            its training size (``fy * object_height_m / reference size``:
            ``read_bop_scene`` works it out), so that an origin off the
            object's centre along the line of sight is placed at its own depth.

        Returns
        -------
        self

        Raises
        ------
        ValueError
            On inconsistent lengths, non-finite poses or poses beyond +-4 pi
            (degrees given as radians), boxes outside their image, or a
            training image without edges.
        """
        self._validate_params()
        trained = train_model(images, poses, boxes=boxes, masks=masks, instances=instances,
                              category=category, edges=self.edges, kernel=self.kernel,
                              morph=self.morph_views, prune=resolve_preset(self.prune),
                              appearance=self.appearance is not None,
                              templates=self.search.rerank == "template", progress=progress,
                              channels=channels, object_height_m=object_height_m,
                              origins=origins, n_threads=self.n_jobs)
        self._set_trained(trained)
        return self

    def partial_fit(self, images: Sequence[ImageLike], poses: ArrayLike, *,
                    boxes: ArrayLike | None = None,
                    masks: Sequence[ImageLike | None] | None = None,
                    instances: Sequence[str] | None = None,
                    progress: Callable[[int], None] | None = None,
                    channels: str = "rgb", origins: ArrayLike | None = None) -> PoseEstimator:
        """Add views or instances to the fitted model: the model a fit on all the data gives.

        Arguments as :meth:`fit`. Only the new images are read;
        :func:`posevote.model.training.extend_model` says what is computed
        again, and why a model with the appearance stages or morphing needs
        a new fit instead.
        """
        self._check_fitted()
        self._validate_params()
        self._set_trained(extend_model(self._trained(), images, poses, boxes=boxes, masks=masks,
                                       instances=instances, edges=self.edges, kernel=self.kernel,
                                       prune=resolve_preset(self.prune), progress=progress,
                                       channels=channels, origins=origins))
        return self

    def _trained(self) -> TrainedModel:
        return TrainedModel(model=self._check_fitted(), full_model=self.full_model_,
                            viewpoint_kappa=self.viewpoint_kappa_, pruning=self.pruning_,
                            appearance=self.appearance_model_, object_height_m=self.object_height_m_)

    def _set_trained(self, trained: TrainedModel) -> None:
        self.model_ = trained.model
        self.full_model_ = trained.full_model
        self.viewpoint_kappa_ = trained.viewpoint_kappa
        self.appearance_model_ = trained.appearance
        self.pruning_ = trained.pruning
        self.object_height_m_ = trained.object_height_m

    def _check_fitted(self) -> PoseModel:
        model = getattr(self, "model_", None)
        if model is None:
            raise not_fitted_error()("this PoseEstimator is not fitted yet; call fit() or "
                                      "load() first")
        return model

    def _appearance_model(self) -> AppearanceModel:
        found = getattr(self, "appearance_model_", None)
        if found is None:
            raise ValueError("the appearance stages need the appearance model learnt when the "
                             "model is fitted; fit (or retrain) with appearance set")
        return found

    # -- estimation --------------------------------------------------------------------
    def setup(self) -> SearchSetup:
        """The search setup of the fitted model with the current parameters."""
        self._check_fitted()
        return SearchSetup(options=self.search, position_sigma=self.kernel.position_sigma,
                           edge_spacing=self.edges.spacing, viewpoint_kappa=self.viewpoint_kappa_,
                           use_weights=self.weights, n_threads=self.n_jobs)

    def _read(self, image: ImageLike, channels: str) -> tuple[EdgeFeatures, NDArray[np.float64]]:
        img = load_image(image, channels=channels)
        return extract_edges(img, self.edges, training=False), img

    def probe(self, image: ImageLike, *, progress: Callable[[int], None] | None = None,
              channels: str = "rgb") -> tuple[ProbeSet, EdgeFeatures]:
        """The probes of p(w) for an image (Fig. 2), before refinement, and its edge features.

        ``progress`` is called with 1 after each probed viewpoint; ``channels`` as in estimate().
        """
        model = self._check_fitted()
        self._validate_params()
        feats, img = self._read(image, channels)
        setup = self.setup()
        maps = search_maps(feats, img.shape, model, setup)
        return self._rerank(probe(model, maps, setup, progress=progress), maps, img), feats

    def estimate(self, image: ImageLike, *, channels: str = "rgb",
                 camera: Camera | None = None) -> PoseEstimate:
        """Find the object and estimate its continuous pose (Sec. II-B).

        Parameters
        ----------
        image : path or ndarray
            The test image: grey, RGB or RGBA; 8-bit, 16-bit or float in [0, 1].
        channels : {"rgb", "bgr"}, optional
            Colour order of an array (``"bgr"``: from ``cv2.imread``).
        camera : Camera, optional
            The test camera: each hypothesis then holds ``R_cam_obj`` and, if
            the model knows the object's height, ``t_cam_obj`` (metres).

        Returns
        -------
        PoseEstimate
            ``found`` is False when the image has no edges or no mode scores
            above ``min_score``.
        """
        start = time.perf_counter()
        self._check_fitted()
        self._validate_params()
        feats, img = self._read(image, channels)
        return self._estimate(feats, img, camera, start)

    def estimate_objects(self, image: ImageLike, max_objects: int, *, channels: str = "rgb",
                         camera: Camera | None = None) -> list[PoseEstimate]:
        """Up to ``max_objects`` objects, best first (each as :meth:`estimate` finds one).

        After each object is found, the edges in its box (grown by
        ``OBJECT_MARGIN``) are taken away and the search runs again on the rest;
        a box overlapping one already found (IoU over ``OBJECT_OVERLAP``) is
        not kept. The list is empty when no object is found.
        """
        start = time.perf_counter()
        self._check_fitted()
        self._validate_params()
        if not (isinstance(max_objects, int) and 1 <= max_objects <= 100):
            raise ValueError(f"max_objects must be an integer in [1, 100], got {max_objects!r}")
        feats, img = self._read(image, channels)
        found: list[PoseEstimate] = []
        while len(found) < max_objects and len(feats):
            result = self._estimate(feats, img, camera, start)
            if result.best is None:
                break
            if all(box_iou(result.best.box, f.best.box) <= OBJECT_OVERLAP for f in found if f.best):
                found.append(result)
            feats = without_box(feats, result.best.box, grow=OBJECT_MARGIN)
            start = time.perf_counter()
        return found

    def _estimate(self, feats: EdgeFeatures, img: NDArray[np.float64], camera: Camera | None,
                  start: float) -> PoseEstimate:
        model = self._check_fitted()
        shape = (int(img.shape[0]), int(img.shape[1]))
        setup = self.setup()
        full = search_maps(feats, shape, model, setup)
        maps: TestMaps | Sequence[TestMaps | None] = full
        # The verification only ranks the first search's probes and moves their
        # boxes itself: they need no polish unless it finds nothing.
        verifying = self.appearance is not None and bool(self.appearance.candidates)
        probes = self._rerank(probe(model, full, setup, polish=not verifying), full, img)
        verified_box = None
        located = None
        # The descriptors read single precision: the image converted once, not per box.
        grey = img.astype(np.float32) if self.appearance is not None else img
        if verifying and self.appearance is not None and probes.score.any():
            located = verify(probes, grey, feats, full, model, self._appearance_model(),
                             self.appearance, setup)
            if located is not None:
                feats, maps, probes, verified_box = located
        if verifying and located is None:
            probes = self._rerank(probe(model, full, setup), full, img)
        modes = find_modes(probes, max_modes=self.max_modes)
        hyps = [refine_mode(probes, v, fit=self.fitting, radius_steps=FIT_RADIUS_STEPS)
                for v in modes]
        recognizing = self.recognition is not None and len(model.instance_names) > 1
        fine = image_maps(feats, shape, setup) if hyps and recognizing else None
        if self.fitting and not self.local_refinement and self.appearance is None and hyps \
                and len(model.instance_names) <= 1:
            # The fit reads the scale a few percent short; the narrow kernel does not
            # (one instance: a category's pooled views pull it onto inner edges).
            hyps[0] = rescale_mode(hyps[0], model, image_maps(feats, shape, setup), setup)
        if self.local_refinement and hyps:
            correlate = self._correlate(img)
            # In object units, at the probes' own scales (after the verification,
            # only those near its box).
            hyps[0] = local_refine(probes, modes[0], hyps[0], model, setup, fitting=self.fitting,
                                   features=feats, shape=shape, maps=fine,
                                   object_units=self.search.object_kernel, correlate=correlate)
            if correlate is not None and not recognizing:
                pixel_maps = image_maps(feats, shape, setup)
                # A plainer side over the other explains itself as fully: the
                # image's own edges decide (measured with the templates).
                pose, turned = half_turn(hyps[0], model, pixel_maps, setup, correlate,
                                         resemble=partial(gradient_similarity, model, img),
                                         features=feats, shape=shape)
                # The search's profile still favours the found pose's side: a turned
                # pose keeps it, as the next mode, with the probability of its side.
                hyps = [pose, *hyps][:self.max_modes] if turned else [pose, *hyps[1:]]
                # The narrow score draws the outline in onto the object's inner
                # edges; the image's edges explained too set the scale.
                hyps[0] = share_scale(hyps[0], model, pixel_maps, setup)
        instance, margin = "", float("nan")
        if recognizing and hyps and fine is not None and self.recognition is not None:
            hyps, instance, margin = recognize(hyps, feats, self.full_model_, maps, fine, setup,
                                               self.recognition, fitting=self.fitting,
                                               local=self.local_refinement)
        if self.appearance is not None and hyps:
            hyps[0] = appearance_refine(hyps[0], grey, model, self._appearance_model(),
                                        self.appearance, verified_box=verified_box)
        if self.appearance is None:
            hyps = [self._outlined(h) for h in hyps]
        kept_hyps = with_probabilities([h for h in hyps if h.score > self.min_score], probes)
        kept = tuple(place_all(kept_hyps, camera, reference_size_px=model.reference_size,
                               object_height_m=self.object_height_m_,
                               anchors=None if camera is None
                               else [self._origin(h) for h in kept_hyps]))
        return PoseEstimate(found=bool(kept), best=kept[0] if kept else None, modes=kept,
                            n_test_features=len(feats), seconds=time.perf_counter() - start,
                            instance=instance if kept else "", instance_margin=margin,
                            top_score=max((h.score for h in hyps), default=0.0),
                            viewpoint_scores=scored_viewpoints(probes))

    def _rerank(self, probes: ProbeSet, maps: TestMaps | Sequence[TestMaps],
                image: NDArray[np.float64]) -> ProbeSet:
        """The best probes re-ranked as ``search.rerank`` says."""
        model = self._check_fitted()
        if self.search.rerank == "coverage":
            return rerank_by_coverage(probes, model, maps, self.setup())
        if self.search.rerank == "template":
            return rerank_by_template(probes, model, image)
        return probes

    def _correlate(self, image: NDArray[np.float64]
                   ) -> Callable[[list[Hypothesis]], NDArray[np.float64]] | None:
        """What weighs poses by the object's grey levels, with the template re-ranking."""
        if self.search.rerank != "template":
            return None
        model = self._check_fitted()

        def correlate(hyps: list[Hypothesis]) -> NDArray[np.float64]:
            return pose_correlations(model, image, *(np.array([getattr(h, name) for h in hyps])
                                                     for name in ("azimuth", "elevation",
                                                                  "inplane", "scale",
                                                                  "position")))
        return correlate

    def _outlined(self, hypothesis: Hypothesis) -> Hypothesis:
        """The hypothesis with the box of its view's outline, where the model has outlines
        (they bound the object tighter than the view's box turned)."""
        outline = outline_at(self._check_fitted(), hypothesis.azimuth, hypothesis.elevation,
                             kappa=self.viewpoint_kappa_, k1_cutoff=K1_CUTOFF)
        if outline is None:
            return hypothesis
        return replace(hypothesis, box=outline_box(outline, hypothesis.position, hypothesis.scale,
                                                   hypothesis.inplane))

    def _origin(self, hypothesis: Hypothesis) -> tuple[float, float, float] | None:
        """The image of the object's origin under a hypothesis and its depth factor (None:
        the box centre at the object's depth)."""
        offset = origin_offset(self._check_fitted(), hypothesis.azimuth, hypothesis.elevation,
                               kappa=self.viewpoint_kappa_, k1_cutoff=K1_CUTOFF)
        if offset is None:
            return None
        u, v = hypothesis.position + hypothesis.scale * rotate_points(offset[:2],
                                                                       hypothesis.inplane)
        return float(u), float(v), float(offset[2])

    # -- persistence -------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write the fitted model to a file (atomically); see :mod:`posevote.model.modelfile`."""
        from posevote.model.modelfile import save_model

        save_model(path, self._trained(), params_to_json(self.get_params(deep=False)),
                   preset=nearest_preset(self.get_params(deep=False),
                                         type(self)().get_params(deep=False)))

    @classmethod
    def load(cls, path: str | Path) -> PoseEstimator:
        """Read an estimator written by :meth:`save`.

        Raises
        ------
        TypeError, FileNotFoundError, ValueError
            A non-path argument; a missing, foreign, corrupt or other-version file.
        """
        from posevote.model.modelfile import load_model

        trained, params = load_model(path)
        try:
            groups = {**OPTION_GROUPS, "prune": PruningPreset}
            est = cls(**params_from_json(params, groups, cls._param_names()))
            est._validate_params()
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{path}: bad parameters in the model file ({exc})") from None
        est._set_trained(trained)
        return est
