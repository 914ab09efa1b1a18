"""The BOP layout (Hodaň et al., Benchmark for 6D Object Pose Estimation): read scenes, write results.

A BOP scene folder holds ``rgb/IMID.png`` (or ``.jpg``), ``mask_visib/IMID_GTIDX.png``,
``scene_gt.json`` (per image id, a list of ``{"cam_R_m2c": 9 numbers,
"cam_t_m2c": 3 numbers in mm, "obj_id": int}``), ``scene_camera.json`` (per image
id, ``{"cam_K": 9 numbers, "depth_scale": ...}``) and ``scene_gt_info.json``
(per image id, one ``{"bbox_obj", "bbox_visib", "visib_fract", ...}`` per
annotation, boxes as ``[x, y, w, h]`` pixels). Ids are written with six digits.

As a training set, each annotation of the object becomes a view: its pose
is ``cam_R_m2c`` read in posevote's angles (:func:`posevote.geometry.pose_from_rotation`),
its box ``bbox_visib``, its mask ``mask_visib``, its distance the depth of
``cam_t_m2c`` (its z: the pinhole's size falls with the depth, not the range).
Results are written in the BOP results CSV,
``scene_id,im_id,obj_id,score,R,t,time``: ``R`` nine numbers row-major and ``t``
three in millimetres, separated by spaces, ``time`` the seconds spent on the image
(the same for all its rows).

Trained on a BOP scene, a model learns where the model's origin lies in each
view, across and along the line of sight (the training set's ``origins``,
``fit(..., origins=)``), so that its ``t_cam_obj``, and the results' ``t``, name
the origin as the ground truth does rather than the box centre
(:mod:`posevote.camera`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from posevote._io import parse_json
from posevote.camera import Camera, object_height_from_distances, origin_depth_factors
from posevote.data.training_set import TrainingSet
from posevote.geometry import pose_from_rotation

#: The header of the BOP results CSV.
RESULTS_HEADER = "scene_id,im_id,obj_id,score,R,t,time"


@dataclass(frozen=True, kw_only=True, eq=False)
class BopScene:
    """The views of one object in a BOP scene.

    Attributes
    ----------
    training_set : TrainingSet
        Images, poses (radians), boxes, masks, distances (metres) and, as
        ``origins``, the image of the model's origin in each view (``cam_K``
        times ``cam_t_m2c``) with its depth factor (the origin's depth over
        the depth a model of these views gives the view:
        :meth:`posevote.estimator.PoseEstimator.fit`).
    cameras : tuple of Camera
        Each view's camera.
    scene_id : int
    im_ids : tuple of int
        Each view's image id.
    rotations : ndarray, shape (K, 3, 3)
        ``cam_R_m2c`` of each view.
    translations_m : ndarray, shape (K, 3)
        ``cam_t_m2c`` of each view, metres.
    """

    training_set: TrainingSet
    cameras: tuple[Camera, ...]
    scene_id: int
    im_ids: tuple[int, ...]
    rotations: NDArray[np.float64]
    translations_m: NDArray[np.float64]


#: The farthest an annotated object may be from the camera, metres (a unit error beyond).
MAX_DISTANCE_M = 1000.0

#: The largest BOP annotation file read (a large scene's ``scene_gt.json`` is a few MB;
#: parsed, JSON takes about ten times its size in memory).
MAX_BOP_JSON_BYTES = 100 << 20


def _load_json(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise FileNotFoundError(f"BOP file not found: {path}")
    size = path.stat().st_size
    if size > MAX_BOP_JSON_BYTES:
        raise ValueError(f"{path}: {size:,} bytes, over the limit of {MAX_BOP_JSON_BYTES:,} "
                         "for a BOP annotation file")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not JSON ({exc})") from None
    data = parse_json(text, str(path))
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected an object keyed by image id")
    return data


def _numbers(value: Any, n: int, *, where: str) -> NDArray[np.float64]:
    try:
        arr = np.asarray(value, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        arr = np.zeros(0)
    if arr.size != n or not np.all(np.isfinite(arr)):
        raise ValueError(f"{where}: expected {n} finite numbers, got {value!r}")
    return arr


def _image_file(folder: Path, kind: str, stem: str) -> Path:
    for suffix in (".png", ".jpg", ".jpeg", ".tif"):
        path = folder / kind / f"{stem}{suffix}"
        if path.is_file():
            return path
    raise FileNotFoundError(f"BOP image not found: {folder / kind / stem}.png")


def _camera(cams: dict[str, Any], key: str, path: Path) -> Camera:
    """The camera of image ``key`` in ``scene_camera.json``."""
    where = f"{path}, image {key}"
    entry = cams.get(key)
    if not isinstance(entry, dict) or "cam_K" not in entry:
        raise ValueError(f"{where}: no cam_K")
    K = _numbers(entry["cam_K"], 9, where=where)
    return Camera.from_dict({"K": K.reshape(3, 3).tolist()}, where=where)


def read_bop_images(scene: str | Path) -> list[tuple[int, Path, Camera]]:
    """Every image of a BOP scene with its id and camera (``scene_camera.json``), by id.

    Raises
    ------
    FileNotFoundError, ValueError
        On missing or malformed files (the message names the file and image id).
    """
    folder = Path(scene)
    path = folder / "scene_camera.json"
    cams = _load_json(path)
    keys = sorted((k for k in cams if k.isdigit()), key=int)
    return [(int(k), _image_file(folder, "rgb", f"{int(k):06d}"), _camera(cams, k, path))
            for k in keys]


def read_bop_scene(scene: str | Path, *, obj_id: int, min_visible: float = 0.1) -> BopScene:
    """The views of object ``obj_id`` in a BOP scene folder (the module docstring).

    Parameters
    ----------
    scene : str or Path
        The scene folder (``.../train/000001``).
    obj_id : int
        The object.
    min_visible : float, optional
        Annotations whose visible fraction is below this are skipped.

    Raises
    ------
    FileNotFoundError, ValueError
        On missing or malformed files (the message names the file and image id).

    Examples
    --------
    >>> import tempfile
    >>> from posevote.data import toy_views
    >>> from posevote.geometry import rotation_from_pose
    >>> images, poses, boxes = toy_views([0, 90])
    >>> folder = write_bop_scene(
    ...     Path(tempfile.mkdtemp()) / "000001", [(255 * im).astype(np.uint8) for im in images],
    ...     [rotation_from_pose(a, 0.0, 0.0) for a in poses], [np.array([0.0, 0.0, 1.0])] * 2,
    ...     Camera(fx=500.0, fy=500.0, cx=64.0, cy=64.0), obj_id=1, boxes=boxes)
    >>> scene = read_bop_scene(folder, obj_id=1)
    >>> scene.scene_id, scene.im_ids, np.degrees(scene.training_set.poses[:, 0]).round(1).tolist()
    (1, (0, 1), [0.0, 90.0])
    """
    folder = Path(scene)
    if not folder.is_dir():
        raise FileNotFoundError(f"BOP scene folder not found: {folder}")
    try:
        scene_id = int(folder.name)
    except ValueError:
        raise ValueError(f"{folder}: a BOP scene folder is named by its id (000001)") from None
    gt = _load_json(folder / "scene_gt.json")
    cams = _load_json(folder / "scene_camera.json")
    info_path = folder / "scene_gt_info.json"
    info = _load_json(info_path)
    images, poses, boxes, masks, dists, cameras, im_ids, rots, trans, origins = (
        [] for _ in range(10))
    for key in sorted(gt, key=lambda k: int(k) if k.isdigit() else -1):
        if not key.isdigit():
            raise ValueError(f"{folder / 'scene_gt.json'}: image id {key!r} is not a number")
        where = f"{folder / 'scene_gt.json'}, image {key}"
        annotations = gt[key]
        if not isinstance(annotations, list):
            raise ValueError(f"{where}: expected a list of annotations")
        camera = _camera(cams, key, folder / "scene_camera.json")
        infos = info.get(key, [])
        if not isinstance(infos, list):
            raise ValueError(f"{info_path}, image {key}: expected a list of annotations")
        for index, ann in enumerate(annotations):
            if not isinstance(ann, dict):
                continue
            found = ann.get("obj_id")
            if isinstance(found, bool) or not isinstance(found, int):
                raise ValueError(f"{where}, annotation {index}: obj_id must be a whole number, "
                                 f"got {found!r}")
            if found != obj_id:
                continue
            R = _numbers(ann.get("cam_R_m2c"), 9, where=f"{where}, cam_R_m2c").reshape(3, 3)
            if not (np.allclose(R @ R.T, np.eye(3), atol=1e-3) and np.linalg.det(R) > 0):
                raise ValueError(f"{where}, annotation {index}: cam_R_m2c is not a rotation")
            t = _numbers(ann.get("cam_t_m2c"), 3, where=f"{where}, cam_t_m2c") / 1000.0
            if not t[2] > 0:
                raise ValueError(f"{where}, annotation {index}: cam_t_m2c puts the object "
                                 f"behind the camera (z = {1000 * t[2]:g} mm)")
            if not np.all(np.abs(t) <= MAX_DISTANCE_M):
                raise ValueError(f"{where}, annotation {index}: cam_t_m2c is "
                                 f"{(1000 * t).tolist()} mm, farther than "
                                 f"{MAX_DISTANCE_M:g} m from the camera")
            entry = infos[index] if index < len(infos) and isinstance(infos[index], dict) else {}
            if float(entry.get("visib_fract", 1.0)) < min_visible:
                continue
            box = _numbers(entry.get("bbox_visib", entry.get("bbox_obj")), 4,
                           where=f"{info_path}, image {key}, annotation {index}")
            if box[2] <= 0 or box[3] <= 0:
                continue
            stem = f"{int(key):06d}"
            images.append(_image_file(folder, "rgb", stem))
            mask = folder / "mask_visib" / f"{stem}_{index:06d}.png"
            masks.append(mask if mask.is_file() else None)
            poses.append(pose_from_rotation(R))
            boxes.append(box)
            dists.append(float(t[2]))
            cameras.append(camera)
            im_ids.append(int(key))
            rots.append(R)
            trans.append(t)
            origins.append(camera.project(t))
    if not images:
        raise ValueError(f"{folder}: no visible annotation of object {obj_id}")
    heights, depths = np.array(boxes)[:, 3], np.array(dists)
    # H from these views, R their median box height (one instance).
    factor = origin_depth_factors(depths, cameras, reference_size_px=float(np.median(heights)),
                                  object_height_m=object_height_from_distances(heights, depths,
                                                                               cameras))
    ts = TrainingSet(images=tuple(images), poses=np.array(poses, dtype=np.float64),
                     boxes=np.array(boxes), masks=tuple(masks),
                     instances=(f"obj{obj_id}",) * len(images), distances=depths,
                     origins=np.column_stack([np.array(origins, dtype=np.float64), factor]))
    return BopScene(training_set=ts, cameras=tuple(cameras), scene_id=scene_id,
                    im_ids=tuple(im_ids), rotations=np.array(rots), translations_m=np.array(trans))


def results_rows(scene_id: int, im_id: int, obj_id: int, score: float,
                 R: Sequence[Sequence[float]] | NDArray, t_m: Sequence[float] | NDArray,
                 seconds: float) -> str:
    """One line of the BOP results CSV (``t`` given in metres, written in millimetres)."""
    R_arr = np.asarray(R, dtype=np.float64).reshape(9)
    t_mm = np.asarray(t_m, dtype=np.float64).reshape(3) * 1000.0
    if not (np.all(np.isfinite(R_arr)) and np.all(np.isfinite(t_mm)) and math.isfinite(score)):
        raise ValueError(f"scene {scene_id}, image {im_id}: R, t and score must be finite")
    return (f"{scene_id},{im_id},{obj_id},{score:.6f},{' '.join(f'{x:.8f}' for x in R_arr)},"
            f"{' '.join(f'{x:.4f}' for x in t_mm)},{seconds:.4f}")


def write_bop_results(path: str | Path, lines: Iterable[str]) -> None:
    """Write the BOP results CSV (header and :func:`results_rows` lines), atomically."""
    from posevote._io import atomic_write_text

    atomic_write_text(path, "\n".join([RESULTS_HEADER, *lines]) + "\n")


def write_bop_scene(folder: str | Path, images: Sequence[NDArray[np.uint8]],
                    rotations: Sequence[NDArray], translations_m: Sequence[NDArray],
                    camera: Camera, *, obj_id: int, boxes: Sequence[Sequence[float]],
                    masks: Sequence[NDArray[np.bool_]] | None = None) -> Path:
    """Write views of one object as a BOP scene folder (one annotation per image)."""
    import cv2

    from posevote._io import atomic_write_text, atomic_write_with

    folder = Path(folder)
    gt, cams, info = {}, {}, {}
    def png(path: Path, pixels: NDArray[np.uint8]) -> None:
        def writer(tmp: Path) -> None:
            if not cv2.imwrite(str(tmp), pixels):
                raise OSError(f"could not write {path}")

        atomic_write_with(path, writer)

    for i, img in enumerate(images):
        stem = f"{i:06d}"
        png(folder / "rgb" / f"{stem}.png", np.asarray(img))
        if masks is not None:
            png(folder / "mask_visib" / f"{stem}_000000.png",
                (np.asarray(masks[i]) > 0).astype(np.uint8) * 255)
        gt[str(i)] = [{"cam_R_m2c": np.asarray(rotations[i], dtype=float).ravel().tolist(),
                       "cam_t_m2c": (np.asarray(translations_m[i], dtype=float) * 1000).tolist(),
                       "obj_id": obj_id}]
        cams[str(i)] = {"cam_K": camera.K.ravel().tolist(), "depth_scale": 1.0}
        box = [float(b) for b in boxes[i]]
        info[str(i)] = [{"bbox_obj": box, "bbox_visib": box, "visib_fract": 1.0}]
    for name, data in (("scene_gt.json", gt), ("scene_camera.json", cams),
                       ("scene_gt_info.json", info)):
        atomic_write_text(folder / name, json.dumps(data))
    return folder
