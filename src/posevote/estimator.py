"""The estimator: training (Sec. II-A, II-C) and estimation (Sec. II-B) in one object.

:class:`PoseEstimator` holds the parameters, fits the model (asking the
estimate's steps what they need learnt), hands each estimate to
:mod:`posevote.pipeline` and reads and writes model files. Every stage is a
plain function of its subpackage and every stage's settings one frozen option
group that validates itself; named, tuned configurations are
:mod:`posevote.presets`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from posevote import pipeline
from posevote._errors import not_fitted_error
from posevote._options import GroupedParams, Options, params_from_json, params_to_json
from posevote.appearance import AppearanceOptions
from posevote.camera import Camera
from posevote.data.images import load_image
from posevote.features.edges import EdgeFeatures, EdgeOptions, extract_edges
from posevote.inference.probes import ProbeSet
from posevote.inference.setup import SearchOptions, SearchSetup
from posevote.model.density import PoseModel
from posevote.model.kernels import KernelOptions
from posevote.model.pruning import PruningPreset, resolve_preset
from posevote.model.training import TrainedModel, extend_model, train_model
from posevote.pipeline import Settings, search_setup
from posevote.presets import get_preset, nearest_preset
from posevote.recognition import RecognitionOptions
from posevote.refinement import RefineOptions
from posevote.results import PoseEstimate
from posevote.templates import TemplateOptions

ImageLike = str | Path | NDArray

#: The option group of each grouped parameter.
OPTION_GROUPS: dict[str, type[Options]] = {
    "edges": EdgeOptions, "kernel": KernelOptions, "search": SearchOptions,
    "refine": RefineOptions, "templates": TemplateOptions, "recognition": RecognitionOptions,
    "appearance": AppearanceOptions}
#: The groups that None switches off (an idea beyond the paper, or recognition).
OPTIONAL_GROUPS = ("templates", "recognition", "appearance")


class PoseEstimator(GroupedParams):
    """Continuous 3D pose of an object in a single image (Teney & Piater 2013).

    Build one from a named preset (:meth:`from_preset`, :mod:`posevote.presets`)
    rather than by hand; every parameter can be overridden there. The estimate
    runs the steps these parameters switch on (:mod:`posevote.pipeline`).

    Parameters
    ----------
    weights : bool, default True
        Weight training features by pose specificity (Eq. 4).
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
        The search grid, its scoring and the coverage re-ranking
        (:class:`posevote.inference.setup.SearchOptions`).
    refine : RefineOptions
        The refinement steps' switches: fit, rescale, local refinement, share
        scale, outline (:class:`posevote.refinement.RefineOptions`).
    prune : {None, "moderate", "aggressive"} or PruningPreset, default None
        Prune a pooled model by clustering (Sec. III-A); the search then runs
        on the cluster centres, recognition and refinement on the full model.
    templates : TemplateOptions or None, default None
        Grey-level templates learnt with the model: the template re-ranking,
        weighing and half-turn check (beyond the paper;
        :class:`posevote.templates.TemplateOptions`). None: off.
    recognition : RecognitionOptions or None
        Instance recognition for models of several instances (Sec. III-B;
        :class:`posevote.recognition.RecognitionOptions`); None: off.
    appearance : AppearanceOptions or None, default None
        HOG verification, box regression and nearest-view viewpoint (beyond
        the paper; :class:`posevote.appearance.AppearanceOptions`);
        learnt when the model is fitted. None: off.
    max_modes : int, default 3
        Modes reported per image.
    min_score : float, default 0.0
        Below this best score the estimate is "not found".
    n_jobs : int, default 1
        Threads probing viewpoints (and reading training images) at once:
        the time of an estimate or of training, not its result.

    Examples
    --------
    >>> from posevote import PoseEstimator
    >>> from posevote.data import toy_views
    >>> images, poses, boxes = toy_views(range(0, 360, 20))
    >>> estimator = PoseEstimator.from_preset("default").fit(images, poses, boxes=boxes)
    >>> test_image = toy_views([40])[0][0]
    >>> round(estimator.estimate(test_image).best.azimuth_deg)
    40
    """

    _groups = OPTION_GROUPS

    def __init__(self, *, weights: bool = True, morph_views: bool = False,
                 edges: EdgeOptions = EdgeOptions(), kernel: KernelOptions = KernelOptions(),
                 search: SearchOptions = SearchOptions(), refine: RefineOptions = RefineOptions(),
                 prune: str | PruningPreset | None = None, templates: TemplateOptions | None = None,
                 recognition: RecognitionOptions | None = RecognitionOptions(),
                 appearance: AppearanceOptions | None = None, max_modes: int = 3,
                 min_score: float = 0.0, n_jobs: int = 1) -> None:
        self.weights, self.morph_views = weights, morph_views
        self.edges, self.kernel, self.search, self.refine = edges, kernel, search, refine
        self.prune, self.templates = prune, templates
        self.recognition, self.appearance = recognition, appearance
        self.max_modes, self.min_score, self.n_jobs = max_modes, min_score, n_jobs

    @classmethod
    def from_preset(cls, name: str, **overrides: Any) -> PoseEstimator:
        """An estimator with the settings of preset ``name``, then ``overrides``.

        ``overrides`` are :meth:`set_params` keys: ``search=SearchOptions(...)``
        replaces a group, ``search__scale_steps=5`` one of its fields.

        Examples
        --------
        >>> PoseEstimator.from_preset("turntable", search__scale_steps=3).search.scale_steps
        3
        """
        return cls(**get_preset(name).params).set_params(**overrides)

    def _validate_params(self) -> None:
        for name in ("weights", "morph_views"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
        for name, cls in OPTION_GROUPS.items():
            value = getattr(self, name)
            optional = name in OPTIONAL_GROUPS
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
        # What the estimate's steps read besides the edges is learnt with them.
        needs = pipeline.artefacts(self._settings())
        trained = train_model(images, poses, boxes=boxes, masks=masks, instances=instances,
                              category=category, edges=self.edges, kernel=self.kernel,
                              morph=self.morph_views, prune=resolve_preset(self.prune),
                              appearance="appearance" in needs, templates="templates" in needs,
                              progress=progress, channels=channels,
                              object_height_m=object_height_m, origins=origins,
                              n_threads=self.n_jobs)
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

    # -- estimation --------------------------------------------------------------------
    def _settings(self) -> Settings:
        return Settings.of(self.get_params(deep=False))

    def setup(self) -> SearchSetup:
        """The search setup of the fitted model with the current parameters."""
        self._check_fitted()
        return search_setup(self._settings(), self._trained())

    def _read(self, image: ImageLike, channels: str) -> tuple[NDArray[np.float64], EdgeFeatures]:
        img = load_image(image, channels=channels)
        return img, extract_edges(img, self.edges, training=False)

    def probe(self, image: ImageLike, *, progress: Callable[[int], None] | None = None,
              channels: str = "rgb") -> tuple[ProbeSet, EdgeFeatures]:
        """The probes of p(w) for an image (Fig. 2), before refinement, and its edge features.

        The search and the re-rankings the settings switch on
        (:data:`posevote.pipeline.SEARCH_STEPS`); ``progress`` is called with 1
        after each probed viewpoint; ``channels`` as in :meth:`estimate`.
        """
        self._check_fitted()
        self._validate_params()
        settings = self._settings()
        steps = pipeline.active_steps(settings, pipeline.SEARCH_STEPS)
        img, feats = self._read(image, channels)
        state = pipeline.begin(settings, self._trained(), img, feats, steps=steps,
                               progress=progress)
        probes = pipeline.run(state, steps).probes
        assert probes is not None
        return probes, feats

    def estimate(self, image: ImageLike, *, channels: str = "rgb",
                 camera: Camera | None = None) -> PoseEstimate:
        """Find the object and estimate its continuous pose (Sec. II-B).

        The steps the parameters switch on run in order
        (:mod:`posevote.pipeline`; ``posevote presets -v`` lists a preset's).

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

        Examples
        --------
        >>> result = estimator.estimate(test_image)
        >>> result.found, round(result.best.azimuth_deg)
        (True, 40)
        """
        start = time.perf_counter()
        self._check_fitted()
        self._validate_params()
        img, feats = self._read(image, channels)
        return pipeline.estimate(self._settings(), self._trained(), img, feats, camera=camera,
                                 start=start)

    def estimate_objects(self, image: ImageLike, max_objects: int, *, channels: str = "rgb",
                         camera: Camera | None = None) -> list[PoseEstimate]:
        """Up to ``max_objects`` objects, best first (each as :meth:`estimate` finds one).

        After each object is found, the edges in its box (grown by
        ``pipeline.OBJECT_MARGIN``) are taken away and the search runs again on
        the rest; a box overlapping one already found (IoU over
        ``pipeline.OBJECT_OVERLAP``) is not kept. The list is empty when no
        object is found.

        Examples
        --------
        >>> [round(r.best.azimuth_deg) for r in estimator.estimate_objects(test_image, 2)]
        [40]
        """
        start = time.perf_counter()
        self._check_fitted()
        self._validate_params()
        if not (isinstance(max_objects, int) and 1 <= max_objects <= 100):
            raise ValueError(f"max_objects must be an integer in [1, 100], got {max_objects!r}")
        img, feats = self._read(image, channels)
        return pipeline.estimate_objects(self._settings(), self._trained(), img, feats,
                                         max_objects, camera=camera, start=start)

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
