"""Training (Sec. II-A, II-C, III-A): pose-annotated images to a weighted, optionally pruned model.

:func:`train_model` reads each training image once: its edges inside the
object's box (and mask), its crop for the morphing between neighbouring
views, and whatever the estimate's steps ask for besides (the templates'
grey levels, the appearance steps' descriptors), learnt by the
:class:`ViewCollector` each extension hands in; then it builds psi
(:func:`posevote.model.density.build_model`), weighs the features (Eq. 4)
and prunes the pooled model (Sec. III-A).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from posevote._parallel import thread_map
from posevote.camera import check_object_height
from posevote.data.images import load_image, read_mask
from posevote.features.edges import (
    EdgeFeatures,
    EdgeOptions,
    box_mask,
    extract_edges,
    normalize_features,
)
from posevote.geometry import box_centre
from posevote.model.density import PoseModel, build_model, viewpoint_kappa
from posevote.model.kernels import ORIENTATION_KAPPA, KernelOptions
from posevote.model.morph import ViewCrops, view_neighbours, view_shifts
from posevote.model.outline import OUTLINE_ANGLES, box_outline, mask_outline
from posevote.model.pruning import PruningPreset, prune_model
from posevote.model.weights import feature_weights


@dataclass(frozen=True, kw_only=True, eq=False)
class AppearanceModel:
    """What the appearance steps learn from the training views
    (:class:`posevote.appearance.model.AppearanceCollector`).

    Attributes
    ----------
    window : (int, int)
        Descriptor window (:func:`~posevote.appearance.descriptors.window_shape`).
    descriptors : ndarray of float32, shape (K, D)
        One descriptor per training view (zeros where its box is too small).
    objectness : ndarray, shape (D + 1,), or None
        The object/background classifier.
    regressor : ndarray, shape (B, 4, D + 1), or None
        The box regressions.
    """

    window: tuple[int, int]
    descriptors: NDArray[np.float32]
    objectness: NDArray[np.float64] | None
    regressor: NDArray[np.float64] | None


class ViewCollector(Protocol):
    """What an extension learns from the training views besides their edges.

    An extension's factory, called with the training boxes (K, 4), gives one
    for a fit. :meth:`read` runs in the threads that read the images,
    :meth:`add` in the images' order (what draws random numbers), then
    :meth:`onto_model` lays per-view arrays on the model before it is weighed
    and pruned, and :meth:`learnt` returns the :class:`TrainedModel` fields
    the extension fills.
    """

    def read(self, image: NDArray[np.float64], box: NDArray[np.float64],
             mask: NDArray[np.bool_] | None, pose: NDArray[np.float64]) -> Any: ...

    def add(self, index: int, read: Any, box: NDArray[np.float64],
            pose: NDArray[np.float64]) -> None: ...

    def with_earlier(self, full: PoseModel, size: NDArray[np.float64]) -> None: ...

    def onto_model(self, model: PoseModel, scales: NDArray[np.float64]) -> PoseModel: ...

    def learnt(self, sizes: NDArray[np.float64], n_threads: int) -> dict[str, Any]: ...


#: Makes an extension's :class:`ViewCollector` from the training boxes.
CollectorFactory = Callable[[NDArray[np.float64]], ViewCollector]


@dataclass(frozen=True, kw_only=True, eq=False)
class TrainedModel:
    """Everything :func:`train_model` learns (what a model file holds).

    Attributes
    ----------
    model : PoseModel
        The searched model (pruned, or the full one).
    full_model : PoseModel
        The full model (recognition and refinement read it).
    viewpoint_kappa : float
        Concentration of the pose kernel K1.
    appearance : AppearanceModel or None
        The appearance stages' model, when asked for.
    pruning : dict or None
        The pruning knobs used (None: not pruned).
    object_height_m : float or None
        The object's height in metres, when known (:mod:`posevote.camera`).
    shrunk : tuple of (float, TrainedModel)
        Each image level over 1 and the model learnt from the views shrunk by it
        (:func:`posevote.pipeline.level_states` searches it on the image as given).
    """

    model: PoseModel
    full_model: PoseModel
    viewpoint_kappa: float
    appearance: AppearanceModel | None = None
    pruning: dict[str, Any] | None = None
    object_height_m: float | None = None
    shrunk: tuple[tuple[float, TrainedModel], ...] = ()

    def at_level(self, level: float) -> TrainedModel:
        """The model searched at image ``level``: itself up to 1, the views shrunk by
        ``level`` over 1.

        Raises
        ------
        ValueError
            If the level is over 1 and the model was not fitted with it.
        """
        if level <= 1.0:
            return self
        for shrink, trained in self.shrunk:
            if shrink == level:
                return trained
        fitted = ", ".join(f"{s:g}" for s, _ in self.shrunk) or "none"
        raise ValueError(f"image level {level:g} searches the training views shrunk by it, "
                         f"learnt at fit (this model's levels over 1: {fitted}); fit the model "
                         "again with these search.image_levels")


#: The largest image level (``SearchOptions.image_levels``): the training views shrunk by it
#: still hold edges.
MAX_LEVEL = 4.0

#: Pose angles beyond this (radians) are refused: they are degrees given as radians.
MAX_POSE_RAD = 4.0 * np.pi


def _check_inputs(images: list[Any], poses: ArrayLike, boxes: ArrayLike | None,
                  masks: Sequence[Any] | None, instances: Sequence[str] | None
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], list[Any], list[str]]:
    k = len(images)
    if k == 0:
        raise ValueError("images: need at least one training image")
    try:
        pose_arr = np.asarray(poses, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"poses must be an array of numbers (radians), got "
                         f"{type(poses).__name__}") from None
    if pose_arr.ndim == 1:
        pose_arr = pose_arr[:, None]
    if pose_arr.ndim != 2 or pose_arr.shape[0] != k or not 1 <= pose_arr.shape[1] <= 3:
        raise ValueError(f"poses must have shape ({k},), ({k}, 2) or ({k}, 3) for {k} images, "
                         f"got {np.shape(poses)}")
    if not np.all(np.isfinite(pose_arr)):
        row = int(np.flatnonzero(~np.all(np.isfinite(pose_arr), axis=1))[0])
        raise ValueError(f"poses: row {row} is not finite ({pose_arr[row].tolist()})")
    if np.abs(pose_arr).max() > MAX_POSE_RAD:
        at = np.unravel_index(int(np.argmax(np.abs(pose_arr))), pose_arr.shape)
        raise ValueError(f"poses: row {at[0]} holds {pose_arr[at]:g}, beyond +-4 pi; poses "
                         "are radians (degrees? pass np.radians(poses))")
    if pose_arr.shape[1] > 1 and np.abs(pose_arr[:, 1]).max() > np.pi / 2 + 1e-9:
        high = int(np.argmax(np.abs(pose_arr[:, 1])))
        raise ValueError(f"poses: row {high} has elevation {pose_arr[high, 1]:g} rad, outside "
                         "[-pi/2, pi/2]")
    pose_arr = np.hstack([pose_arr, np.zeros((k, 3 - pose_arr.shape[1]))])
    try:
        box_arr = (np.full((k, 4), np.nan) if boxes is None
                   else np.asarray(boxes, dtype=np.float64))
    except (TypeError, ValueError):
        raise ValueError("boxes must be an array of numbers, shape (K, 4)") from None
    if box_arr.ndim == 1 and box_arr.size == 4 * k:
        box_arr = box_arr.reshape(k, 4)
    if box_arr.shape != (k, 4):
        raise ValueError(f"boxes must have shape ({k}, 4) for {k} images, got {box_arr.shape}")
    mask_list = list(masks) if masks is not None else [None] * k
    if len(mask_list) != k:
        raise ValueError(f"masks must have {k} entries, got {len(mask_list)}")
    names = list(instances) if instances is not None else ["object"] * k
    if len(names) != k:
        raise ValueError(f"instances must have {k} entries, got {len(names)}")
    bad = [i for i, n in enumerate(names) if not isinstance(n, str) or not n]
    if bad:
        raise ValueError(f"instances[{bad[0]}] must be a non-empty string, got {names[bad[0]]!r}")
    return pose_arr, box_arr, mask_list, names


def _object_box(label: str, img: NDArray[np.float64], box: NDArray[np.float64],
                mask: NDArray[np.bool_] | None) -> NDArray[np.float64]:
    """The training box: given, else the mask's, else the whole image; checked inside it."""
    if np.all(np.isnan(box)):
        if mask is not None:
            rows, cols = np.nonzero(mask)
            return np.array([cols.min(), rows.min(), np.ptp(cols) + 1, np.ptp(rows) + 1],
                            dtype=float)
        return np.array([0.0, 0.0, img.shape[1], img.shape[0]])
    if not np.all(np.isfinite(box)):
        raise ValueError(f"{label}: box {box.tolist()} has NaN values")
    x, y, w, h = box
    if w <= 0 or h <= 0 or x < -0.5 or y < -0.5 or x + w > img.shape[1] + 0.5 \
            or y + h > img.shape[0] + 0.5:
        raise ValueError(f"{label}: box (x={x:g}, y={y:g}, w={w:g}, h={h:g}) is not inside "
                         f"the {img.shape[1]}x{img.shape[0]} image")
    return box


def _read_mask(label: str, mask: Any, shape: tuple[int, ...]) -> NDArray[np.bool_] | None:
    if mask is None:
        return None
    if not isinstance(mask, np.ndarray):
        mask = read_mask(mask)
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != shape:
        raise ValueError(f"{label}: mask shape {mask.shape} differs from image shape {shape}")
    if not mask.any():
        raise ValueError(f"{label}: the mask is empty")
    return mask


def train_model(images: Sequence[str | Path | NDArray], poses: ArrayLike, *,
                boxes: ArrayLike | None = None, masks: Sequence[Any] | None = None,
                instances: Sequence[str] | None = None, category: str = "",
                edges: EdgeOptions = EdgeOptions(), kernel: KernelOptions = KernelOptions(),
                morph: bool = False, prune: PruningPreset | None = None,
                collect: Sequence[CollectorFactory] = (),
                progress: Callable[[int], None] | None = None,
                channels: str = "rgb", object_height_m: float | None = None,
                origins: ArrayLike | None = None, n_threads: int = 1,
                levels: Sequence[float] = ()) -> TrainedModel:
    """Learn a model from pose-annotated images (Sec. II-A, II-C, III-A).

    Parameters
    ----------
    images, poses, boxes, masks, instances, category, progress, channels, object_height_m, origins
        As in :meth:`posevote.estimator.PoseEstimator.fit`.
    edges : EdgeOptions
        Edge extraction.
    kernel : KernelOptions
        Kernel widths (the weights of Eq. 4 and the pose kernel K1).
    morph : bool
        Measure the features' motion between neighbouring views.
    prune : PruningPreset or None
        Prune the pooled model with these knobs.
    collect : sequence of callable
        What the estimate's steps ask for besides the edges: each factory's
        :class:`ViewCollector` learns it from the views.
    n_threads : int, optional
        Threads reading the images and weighing the instances' features: the
        time of training, not its result.
    levels : sequence of float, optional
        Image levels searched; for each over 1 a model is also learnt from the
        views shrunk by it (``TrainedModel.shrunk``: a small object's edges as the
        camera sees them, searched near scale 1; ``progress`` counts the first
        reading only).

    Returns
    -------
    TrainedModel
    """
    height = check_object_height(object_height_m)
    if isinstance(images, (str, Path)):
        raise TypeError(f"images must be a sequence of image paths or arrays, got the single "
                        f"path {str(images)!r} (read a training folder with read_poses_csv)")
    images = list(images)

    def learn(shrink: float) -> TrainedModel:
        views = _extract(images, poses, boxes, masks, instances, edges=edges, morph=morph,
                         collect=collect, progress=progress if shrink == 1.0 else None,
                         channels=channels, n_threads=n_threads, origins=origins,
                         shrink=shrink)
        return _pool(views, category=category, kernel=kernel, prune=prune, height=height,
                     n_threads=n_threads)

    return replace(learn(1.0), shrunk=tuple(
        (level, learn(1.0 / level)) for level in sorted({float(v) for v in levels if v > 1.0})))


@dataclass(kw_only=True, eq=False)
class _Views:
    """What training reads from each image, before the views are pooled."""

    feats: list[EdgeFeatures]
    centres: NDArray[np.float64]
    sizes: NDArray[np.float64]
    poses: NDArray[np.float64]
    names: list[str]
    collectors: Sequence[ViewCollector] = ()
    crops: ViewCrops | None = None
    origins: NDArray[np.float64] | None = None
    outlines: NDArray[np.float64] | None = None


def _extract(images: list[Any], poses: ArrayLike, boxes: ArrayLike | None,
             masks: Sequence[Any] | None, instances: Sequence[str] | None, *,
             edges: EdgeOptions, morph: bool, collect: Sequence[CollectorFactory],
             progress: Callable[[int], None] | None, channels: str, n_threads: int = 1,
             origins: ArrayLike | None = None, shrink: float = 1.0) -> _Views:
    """Each image's edges inside its box (and mask), box and pose (``n_threads`` images at a
    time), each image first resized by ``shrink`` (its box, mask and origin with it)."""
    pose_arr, box_arr, mask_list, names = _check_inputs(images, poses, boxes, masks, instances)
    k = len(images)
    origin_arr = None if origins is None else _check_origins(origins, k)
    if origin_arr is not None and shrink != 1.0:
        origin_arr = np.column_stack([(origin_arr[:, :2] + 0.5) * shrink - 0.5,
                                      origin_arr[:, 2:]])
    feats, centres, sizes = [], np.zeros((k, 2)), np.zeros((k, 2))
    outlines, masked = np.zeros((k, OUTLINE_ANGLES)), False
    collectors = [make(box_arr) for make in collect]
    crops = ViewCrops() if morph else None

    def read(i: int) -> tuple[NDArray[np.float64], NDArray[np.float64], EdgeFeatures,
                              list[Any], NDArray[np.float64] | None]:
        """Image ``i``, its box, its edges inside the box (and mask), what each collector
        reads of it, and its mask's outline."""
        image = images[i]
        label = str(image) if isinstance(image, (str, Path)) else f"images[{i}]"
        img = load_image(image, name=label, channels=channels)
        if shrink != 1.0:
            label += (f" (shrunk by {1.0 / shrink:g} for its image level; leave the level out "
                      "of search.image_levels where the views are this small)")
        mask = _read_mask(label, mask_list[i], img.shape)
        box = _object_box(label, img, box_arr[i], mask)
        if shrink != 1.0:
            img, mask, box = _shrunk(img, mask, box, shrink)
        region = box_mask(img.shape, box)
        if mask is not None:
            # The mask grown by 2 pixels: edges on the outline stay.
            grown = cv2.dilate(mask.astype(np.uint8), np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]],
                                                                dtype=np.uint8), iterations=2)
            region &= grown.astype(bool)
        f = extract_edges(img, edges, training=True, mask=region)
        if len(f) == 0:
            raise ValueError(f"{label}: no edges found on the object; check the box/mask "
                             "or lower EdgeOptions.thresholds")
        inside = None if mask is None else mask & box_mask(img.shape, box)
        return (img, box, f, [c.read(img, box, mask, pose_arr[i]) for c in collectors],
                mask_outline(inside, box_centre(box), float(pose_arr[i, 2]))
                if inside is not None and inside.any() else None)

    # Images are read in threads; what draws random boxes runs here, in order.
    for i, (img, box, f, reads, outline) in enumerate(thread_map(read, range(k), n_threads)):
        feats.append(f)
        outlines[i] = box_outline(box[2:]) if outline is None else outline
        masked |= outline is not None
        for collector, item in zip(collectors, reads, strict=True):
            collector.add(i, item, box, pose_arr[i])
        if crops is not None:
            crops.add(img, box)
        centres[i] = box_centre(box)
        sizes[i] = box[2:]
        if progress is not None:
            progress(1)
    return _Views(feats=feats, centres=centres, sizes=sizes, poses=pose_arr, names=names,
                  collectors=collectors, crops=crops, origins=origin_arr,
                  outlines=outlines if masked else None)


def _shrunk(img: NDArray[np.float64], mask: NDArray[np.bool_] | None, box: NDArray[np.float64],
            shrink: float) -> tuple[NDArray[np.float64], NDArray[np.bool_] | None,
                                    NDArray[np.float64]]:
    """The image (area-averaged), its mask and its box resized by ``shrink`` (pixel centres
    kept)."""
    h, w = img.shape[:2]
    size = (max(1, int(round(w * shrink))), max(1, int(round(h * shrink))))
    small = np.asarray(cv2.resize(np.asarray(img, dtype=np.float32), size,
                                  interpolation=cv2.INTER_AREA), dtype=np.float64)
    if mask is not None:
        mask = cv2.resize(mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    x, y, bw, bh = box
    return small, mask, np.array([(x + 0.5) * shrink - 0.5, (y + 0.5) * shrink - 0.5,
                                  bw * shrink, bh * shrink])


def _check_origins(origins: ArrayLike, k: int) -> NDArray[np.float64]:
    """``origins`` as a (K, 2) or (K, 3) array of finite numbers (the third positive), or a
    ValueError naming the row."""
    try:
        arr = np.asarray(origins, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("origins must be an array of numbers, shape (K, 2) or (K, 3)") from None
    if arr.ndim != 2 or arr.shape[0] != k or arr.shape[1] not in (2, 3):
        raise ValueError(f"origins must have shape ({k}, 2) or ({k}, 3) for {k} images, got "
                         f"{arr.shape}")
    if not np.all(np.isfinite(arr)):
        row = int(np.flatnonzero(~np.all(np.isfinite(arr), axis=1))[0])
        raise ValueError(f"origins: row {row} is not finite ({arr[row].tolist()})")
    if arr.shape[1] == 3 and not np.all(arr[:, 2] > 0):
        row = int(np.flatnonzero(arr[:, 2] <= 0)[0])
        raise ValueError(f"origins: row {row} has a depth factor {arr[row, 2]:g}; it must be "
                         "positive")
    # Finite but absurd: pixels past any image, a depth factor in other units.
    far = np.any(np.abs(arr[:, :2]) > 1e6, axis=1)
    if arr.shape[1] == 3:
        far |= ~((arr[:, 2] >= 1e-3) & (arr[:, 2] <= 1e3))
    if far.any():
        row = int(np.flatnonzero(far)[0])
        raise ValueError(f"origins: row {row} is {arr[row].tolist()}; expected pixels within "
                         "1e6 and a depth factor from 1e-3 to 1e3")
    return arr


def _pool(views: _Views, *, category: str, kernel: KernelOptions, prune: PruningPreset | None,
          height: float | None, n_threads: int = 1) -> TrainedModel:
    """psi from the views (Sec. II-A), the weights (Eq. 4) and the pruning (Sec. III-A)."""
    feats, centres, sizes, pose_arr, names = (views.feats, views.centres, views.sizes,
                                              views.poses, views.names)
    crops = views.crops
    instance_names = sorted(set(names))
    inst_index = np.array([instance_names.index(n) for n in names])
    # Each instance keeps its own typical size; instances are brought to the
    # common reference size (the median of their median box heights).
    inst_height = np.array([np.median(sizes[inst_index == j, 1])
                            for j in range(len(instance_names))])
    reference = float(np.median(inst_height))
    inst_size = inst_height / reference
    scales = inst_size[inst_index]
    model = build_model(feats, poses=pose_arr, centers=centres, scales=scales, box_sizes=sizes,
                        instances=inst_index, instance_names=instance_names,
                        reference_size=reference, category=category,
                        instance_size=inst_size.tolist())
    if views.origins is not None:
        # In the features' frame: from the reference point, upright, in reference pixels
        # (a depth factor, if given, as it is).
        offsets = np.vstack([normalize_features(
            EdgeFeatures(xy=views.origins[k:k + 1, :2], theta=np.zeros(1)), center=centres[k],
            scale=float(scales[k]), inplane=float(pose_arr[k, 2])).xy
            for k in range(len(feats))])
        model = replace(model, view_origin=np.hstack([offsets, views.origins[:, 2:]]))
    for collector in views.collectors:
        model = collector.onto_model(model, scales)
    if views.outlines is not None:
        model = replace(model, view_outline=views.outlines / scales[:, None])
    if crops is not None:
        neighbours = view_neighbours(model.view_azimuth, model.view_elevation,
                                     model.view_instance)
        model = replace(model, view_neighbour=neighbours, shift=view_shifts(
            feats, crops, neighbours, centers=centres, scales=scales, inplanes=pose_arr[:, 2]))
    kappa = viewpoint_kappa(model, kernel.viewpoint_bandwidth_deg)
    weights = feature_weights(model, position_sigma=kernel.position_sigma,
                              orientation_kappa=ORIENTATION_KAPPA, viewpoint_kappa=kappa,
                              n_threads=n_threads)
    full = model.with_weights(weights)
    searched = full if prune is None else prune_model(
        full, prune, position_sigma=kernel.position_sigma, orientation_kappa=ORIENTATION_KAPPA)
    learnt: dict[str, Any] = {}
    for collector in views.collectors:
        learnt.update(collector.learnt(sizes, n_threads))
    return TrainedModel(model=searched, full_model=full, viewpoint_kappa=kappa,
                        pruning=None if prune is None else asdict(prune), object_height_m=height,
                        **learnt)


def _outlines(full: PoseModel, size: NDArray[np.float64], new: _Views
              ) -> NDArray[np.float64] | None:
    """The old and new views' outlines at their training sizes (a view without a mask:
    its box), None if no view has one."""
    if full.view_outline is None and new.outlines is None:
        return None
    old = full.view_outline if full.view_outline is not None \
        else np.array([box_outline(b) for b in full.view_box]).reshape(-1, OUTLINE_ANGLES)
    added = new.outlines if new.outlines is not None \
        else np.array([box_outline(b) for b in new.sizes]).reshape(-1, OUTLINE_ANGLES)
    return np.vstack([old * size[full.view_instance][:, None], added])


def extend_model(trained: TrainedModel, images: Sequence[str | Path | NDArray], poses: ArrayLike,
                 *, boxes: ArrayLike | None = None, masks: Sequence[Any] | None = None,
                 instances: Sequence[str] | None = None, edges: EdgeOptions = EdgeOptions(),
                 kernel: KernelOptions = KernelOptions(), prune: PruningPreset | None = None,
                 collect: Sequence[CollectorFactory] = (),
                 progress: Callable[[int], None] | None = None,
                 channels: str = "rgb", origins: ArrayLike | None = None) -> TrainedModel:
    """The model of ``trained``'s views and the new ones: what a training on all of them gives.

    Only the new images are read. The views already learnt are taken back
    from the full model (each feature at its view's training size, upright),
    and everything that depends on all the views is computed again: the
    instances' sizes and the reference size, the pose kernel's
    concentration, the weights of Eq. 4 (a view's weight depends on every
    other view) and the pruning. The appearance model (its classifier and box
    regressions are trained on crops of every image) and the morphing (its
    flow between neighbouring views) need the old images, so such a model
    must be trained again on all of them. ``collect`` learns the new views'
    share of what the model holds besides the edges (its templates), each
    collector taking the earlier views' share from the model.

    Raises
    ------
    ValueError
        On a model with the appearance stages or morphing, new views with
        ``origins`` for a model without them or the other way round, or bad
        new input (as :func:`train_model`).
    """
    full = trained.full_model
    if trained.appearance is not None or full.shift is not None:
        raise ValueError("this model has the appearance stages or morphing, which are learnt "
                         "from every training image: fit it again on all the images")
    if (origins is None) != (full.view_origin is None):
        raise ValueError("origins: give them for the new views exactly when the model was "
                         "fitted with them" + (" (it was)" if origins is None else
                                               " (it was not)"))
    if origins is not None and full.view_origin is not None \
            and np.shape(origins)[-1] != full.view_origin.shape[1]:
        raise ValueError(f"origins: the model's have {full.view_origin.shape[1]} columns, the "
                         f"new views' {np.shape(origins)[-1]}")
    if isinstance(images, (str, Path)):
        raise TypeError(f"images must be a sequence of image paths or arrays, got the single "
                        f"path {str(images)!r}")
    images = list(images)

    def read(shrink: float) -> _Views:
        return _extract(images, poses, boxes, masks, instances, edges=edges, morph=False,
                        collect=collect, progress=progress if shrink == 1.0 else None,
                        channels=channels, origins=origins, shrink=shrink)

    return replace(_extended(trained, read(1.0), kernel=kernel, prune=prune), shrunk=tuple(
        (level, _extended(small, read(1.0 / level), kernel=kernel, prune=prune))
        for level, small in trained.shrunk))


def _extended(trained: TrainedModel, new: _Views, *, kernel: KernelOptions,
              prune: PruningPreset | None) -> TrainedModel:
    """``trained``'s views (taken back from its full model) pooled with ``new``."""
    full = trained.full_model
    size = np.asarray(full.instance_size or [1.0] * len(full.instance_names), dtype=np.float64)
    old_feats = []
    for k in range(full.n_views):
        s = size[full.view_instance[k]]
        sel = full.view == k
        old_feats.append(EdgeFeatures(xy=full.xy[sel] * s, theta=full.theta[sel].copy()))
    old_sizes = full.view_box * size[full.view_instance][:, None]
    old_poses = np.column_stack([full.view_azimuth, full.view_elevation,
                                 np.zeros(full.n_views)])
    for collector in new.collectors:
        collector.with_earlier(full, size)
    views = _Views(feats=old_feats + new.feats,
                   centres=np.vstack([np.zeros((full.n_views, 2)), new.centres]),
                   sizes=np.vstack([old_sizes, new.sizes]),
                   poses=np.vstack([old_poses, new.poses]),
                   names=[full.instance_names[i] for i in full.view_instance] + new.names,
                   origins=None if full.view_origin is None or new.origins is None else np.vstack(
                       [np.hstack([full.view_origin[:, :2] * size[full.view_instance][:, None],
                                   full.view_origin[:, 2:]]), new.origins]),
                   collectors=new.collectors, outlines=_outlines(full, size, new))
    return _pool(views, category=full.category, kernel=kernel, prune=prune,
                 height=trained.object_height_m)
