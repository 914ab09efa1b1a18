"""The estimator: training (Sec. II-A, II-C) and estimation (Sec. II-B) in one object.

:class:`PoseEstimator` holds the parameters, fits the model (and what the
estimate's steps ask for), hands each estimate to :mod:`posevote.pipeline`
and reads and writes model files; named configurations are :mod:`posevote.presets`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from numpy.typing import ArrayLike, NDArray

from posevote import pipeline
from posevote._errors import not_fitted_error
from posevote._options import GroupedParams, params_from_json, params_to_json
from posevote.appearance import AppearanceOptions
from posevote.camera import Camera
from posevote.data.images import load_image
from posevote.features.edges import EdgeFeatures, EdgeOptions, extract_edges
from posevote.inference.probes import ProbeSet
from posevote.inference.setup import SearchOptions, SearchSetup
from posevote.model.kernels import KernelOptions
from posevote.model.modelfile import load_model, save_model
from posevote.model.pruning import PruningPreset, resolve_preset
from posevote.model.training import TrainedModel, extend_model, train_model
from posevote.presets import get_preset, nearest_preset
from posevote.recognition import RecognitionOptions
from posevote.refinement import RefineOptions
from posevote.results import PoseEstimate
from posevote.templates import TemplateOptions

ImageLike = str | Path | NDArray


class PoseEstimator(GroupedParams):
    """Continuous 3D pose of an object in a single image (Teney & Piater 2013).

    Build one from a named preset (:meth:`from_preset`), overriding what differs; an
    estimate runs the steps these parameters switch on (:mod:`posevote.pipeline`).

    Parameters
    ----------
    weights : bool, default True
        Weight training features by pose specificity (Eq. 4).
    morph_views : bool, default False
        Move features with the object between training views (:mod:`posevote.model.morph`).
    edges, kernel, search, refine : option groups
        Edge extraction, kernel widths, the search's grid and scoring, the refinement
        steps' switches (:class:`~posevote.refinement.RefineOptions`).
    prune : {None, "moderate", "aggressive"} or PruningPreset, default None
        Prune a pooled model by clustering for the search (Sec. III-A).
    templates, recognition, appearance : option group or None
        The grey-level template steps, instance recognition (Sec. III-B), the HOG appearance
        steps (:mod:`~posevote.templates`, :mod:`~posevote.recognition`,
        :mod:`~posevote.appearance`); None: off.
    max_modes : int, default 3
        Modes reported per image.
    min_score : float, default 0.0
        A mode whose detection score is below this is dropped; none left: "not
        found". The detection score is the mode's contrast where
        ``SearchOptions.contrast`` measures it, else its score.
    n_jobs : int, default 1
        Threads probing viewpoints and reading training images (the time, not the result).

    Examples
    --------
    >>> from posevote import PoseEstimator
    >>> from posevote.data import toy_views
    >>> images, poses, boxes = toy_views(range(0, 360, 20))
    >>> estimator = PoseEstimator.from_preset("default").fit(images, poses, boxes=boxes)
    >>> result = estimator.estimate(toy_views([50])[0][0])
    >>> result.found, round(result.best.azimuth_deg)
    (True, 52)
    """

    _groups = pipeline.OPTION_GROUPS

    def __init__(self, *, weights: bool = True, morph_views: bool = False,
                 edges: EdgeOptions = EdgeOptions(), kernel: KernelOptions = KernelOptions(),
                 search: SearchOptions = SearchOptions(), refine: RefineOptions = RefineOptions(),
                 prune: str | PruningPreset | None = None, templates: TemplateOptions | None = None,
                 recognition: RecognitionOptions | None = RecognitionOptions(),
                 appearance: AppearanceOptions | None = None, max_modes: int = 3,
                 min_score: float = 0.0, n_jobs: int = 1) -> None:
        self.weights, self.morph_views, self.edges, self.kernel = weights, morph_views, edges, kernel
        self.search, self.refine, self.prune, self.templates = search, refine, prune, templates
        self.recognition, self.appearance, self.max_modes = recognition, appearance, max_modes
        self.min_score, self.n_jobs = min_score, n_jobs

    @classmethod
    def from_preset(cls, name: str, **overrides: Any) -> PoseEstimator:
        """An estimator with the settings of preset ``name``, then ``overrides``
        (:meth:`set_params` keys: ``refine=RefineOptions(...)``, ``search__scale_steps=5``).

        Examples
        --------
        >>> PoseEstimator.from_preset("cluttered", refine__share_scale=False).refine.local
        'profile'
        """
        return cls(**get_preset(name).params).set_params(**overrides)

    def _settings(self) -> pipeline.Settings:
        return pipeline.Settings.of(self.get_params(deep=False))

    def fit(self, images: Sequence[ImageLike], poses: ArrayLike, *,
            boxes: ArrayLike | None = None, masks: Sequence[ImageLike | None] | None = None,
            instances: Sequence[str] | None = None, category: str = "",
            progress: Callable[[int], None] | None = None, channels: str = "rgb",
            object_height_m: float | None = None, origins: ArrayLike | None = None) -> PoseEstimator:
        """Learn the model from pose-annotated images (Sec. II-A, II-C) and what the steps ask for.

        Parameters
        ----------
        images : sequence of (path or ndarray)
            Training images (grey, RGB, RGBA; 8-bit, 16-bit or float).
        poses : array_like, shape (K,), (K, 2) or (K, 3)
            Azimuth, optionally elevation and in-plane angle, radians.
        boxes : array_like, shape (K, 4), optional
            Object boxes ``(x, y, w, h)``, pixels; a NaN row: the mask's box, else the image.
        masks : sequence of (path, ndarray or None), optional
            Object masks; edges are kept only inside (grown by 2 pixels).
        instances, category : sequence of str, str, optional
            Each image's instance (None: one instance); the category's name.
        progress : callable, optional
            Called with 1 after each image is processed.
        channels : {"rgb", "bgr"}, optional
            Colour order of array images (``"bgr"``: from ``cv2.imread``).
        object_height_m : float, optional
            The object's height in metres, so that a camera places it in depth.
        origins : array_like, shape (K, 2) or (K, 3), optional
            The image ``(u, v)`` of the object's origin in each training image
            (``t_cam_obj`` names it), and its depth factor
            (:func:`posevote.camera.origin_depth_factors`).

        Returns
        -------
        self

        Raises
        ------
        ValueError
            Inconsistent lengths, poses not finite or past +-4 pi (degrees?), a box outside
            its image, a training image without edges (the message names the image or row).

        Examples
        --------
        >>> images, poses, boxes = toy_views(range(0, 360, 20))
        >>> PoseEstimator().fit(images, poses, boxes=boxes).model_.n_views
        18
        """
        self._set_trained(train_model(
            images, poses, boxes=boxes, masks=masks, instances=instances, category=category,
            edges=self.edges, kernel=self.kernel, morph=self.morph_views,
            prune=resolve_preset(self.prune),
            collect=pipeline.collectors(pipeline.artefacts(self._settings())), progress=progress,
            channels=channels, object_height_m=object_height_m, origins=origins,
            n_threads=self.n_jobs, levels=self._settings().search.image_levels))
        return self

    def partial_fit(self, images: Sequence[ImageLike], poses: ArrayLike, *,
                    boxes: ArrayLike | None = None, masks: Sequence[ImageLike | None] | None = None,
                    instances: Sequence[str] | None = None, progress: Callable[[int], None] | None = None,
                    channels: str = "rgb", origins: ArrayLike | None = None) -> PoseEstimator:
        """Add views or instances to the fitted model: the model a fit on all the data gives.

        Arguments as :meth:`fit`; only the new images are read (what is learnt again,
        and which models need a new fit: :func:`posevote.model.training.extend_model`).

        Examples
        --------
        >>> images, poses, boxes = toy_views(range(0, 360, 20))
        >>> est = PoseEstimator().fit(images[::2], poses[::2], boxes=boxes[::2])
        >>> est.partial_fit(images[1::2], poses[1::2], boxes=boxes[1::2]).model_.n_views
        18
        """
        trained, _ = self._trained(), self._settings()
        self._set_trained(extend_model(trained, images, poses, boxes=boxes, masks=masks,
                                       instances=instances, edges=self.edges, kernel=self.kernel,
                                       prune=resolve_preset(self.prune), progress=progress,
                                       collect=pipeline.collectors(pipeline.held(trained)),
                                       channels=channels, origins=origins))
        return self

    def _trained(self) -> TrainedModel:
        if getattr(self, "model_", None) is None:
            raise not_fitted_error()("this PoseEstimator is not fitted yet; call fit() or load() "
                                      "first")
        return TrainedModel(model=self.model_, full_model=self.full_model_, pruning=self.pruning_,
                            viewpoint_kappa=self.viewpoint_kappa_, appearance=self.appearance_model_,
                            object_height_m=self.object_height_m_, shrunk=self.shrunk_models_)

    def _set_trained(self, trained: TrainedModel) -> None:
        self.model_, self.full_model_, self.pruning_ = trained.model, trained.full_model, trained.pruning
        self.viewpoint_kappa_, self.appearance_model_ = trained.viewpoint_kappa, trained.appearance
        self.object_height_m_, self.shrunk_models_ = trained.object_height_m, trained.shrunk

    def setup(self) -> SearchSetup:
        """The search setup of the fitted model with the current parameters."""
        return pipeline.search_setup(self._settings(), self._trained())

    def _image(self, image: ImageLike, channels: str, camera: Camera | None) -> NDArray:
        img = load_image(image, channels=channels)
        if isinstance(camera, Camera):
            img = camera.undistort(img)   # the poses are the undistorted camera's
        return img

    def _begin(self, image: ImageLike, channels: str, names: Sequence[str] | None = None,
               **kw: Any) -> tuple[pipeline.EstimateState, list[pipeline.Step]]:
        trained, settings = self._trained(), self._settings()
        steps = pipeline.active_steps(settings, names)
        img = self._image(image, channels, kw.get("camera"))
        return pipeline.begin(settings, trained, img, extract_edges(img, self.edges, training=False),
                              steps=steps, **kw), steps

    def probe(self, image: ImageLike, *, progress: Callable[[int], None] | None = None,
              channels: str = "rgb") -> tuple[ProbeSet, EdgeFeatures]:
        """The probes of p(w) for an image (Fig. 2) and its edge features: the search steps
        the parameters switch on (``progress``: called with 1 after each viewpoint)."""
        done = pipeline.run(*self._begin(image, channels, pipeline.SEARCH_STEPS,
                                         progress=progress))
        assert done.probes is not None
        return done.probes, done.features

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
            The test camera: each mode then holds ``R_cam_obj``, and ``t_cam_obj``
            (metres) where the model knows the object's height; an image from a
            lens with distortion (``Camera.dist``) is undistorted first, and the
            poses are the undistorted camera's.

        Returns
        -------
        PoseEstimate
            ``found`` is False when the image has no edges or no mode's detection score is
            over ``min_score``.

        Examples
        --------
        >>> result = estimator.estimate(toy_views([130])[0][0])
        >>> round(result.best.azimuth_deg), len(result.modes), result.ambiguous
        (128, 3, False)
        """
        start = time.perf_counter()
        settings = self._settings()
        return pipeline.estimate_levels(settings, self._trained(),
                                        self._image(image, channels, camera), self.edges,
                                        pipeline.active_steps(settings, None), camera=camera,
                                        start=start)

    def estimate_objects(self, image: ImageLike, max_objects: int, *, channels: str = "rgb",
                         camera: Camera | None = None) -> list[PoseEstimate]:
        """Up to ``max_objects`` objects, best first, each found as :meth:`estimate` finds
        one (:func:`posevote.pipeline.estimate_objects`); none found: an empty list.

        Examples
        --------
        >>> [round(r.best.azimuth_deg) for r in estimator.estimate_objects(
        ...     toy_views([50])[0][0], 2)]
        [52]
        """
        start = time.perf_counter()
        pipeline.check_max_objects(max_objects)
        settings = self._settings()
        return pipeline.objects_at_levels(settings, self._trained(),
                                          self._image(image, channels, camera), self.edges,
                                          pipeline.active_steps(settings, None), max_objects,
                                          camera=camera, start=start)

    def save(self, path: str | Path) -> None:
        """Write the fitted model to a file (atomically); see :mod:`posevote.model.modelfile`.

        Examples
        --------
        >>> import pathlib, tempfile
        >>> estimator.save(pathlib.Path(tempfile.mkdtemp()) / "toy.npz")
        """
        params = self.get_params(deep=False)
        save_model(path, self._trained(), params_to_json(params),
                   preset=nearest_preset(params, type(self)().get_params(deep=False)))

    @classmethod
    def load(cls, path: str | Path) -> PoseEstimator:
        """Read an estimator written by :meth:`save`.

        Raises
        ------
        TypeError, FileNotFoundError, ValueError
            A non-path argument; a missing, foreign, corrupt or other-version file.

        Examples
        --------
        >>> import pathlib, tempfile
        >>> estimator.save(path := pathlib.Path(tempfile.mkdtemp()) / "toy.npz")
        >>> PoseEstimator.load(path).min_score, PoseEstimator.load(path).model_.n_views
        (0.54, 18)
        """
        trained, params = load_model(path)
        try:
            groups = {**pipeline.OPTION_GROUPS, "prune": PruningPreset}
            est = cls(**params_from_json(params, groups, cls._param_names()))
            est._settings()
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{path}: bad parameters in the model file ({exc})") from None
        est._set_trained(trained)
        return est
