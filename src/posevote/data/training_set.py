"""Pose-annotated training sets: the ``poses.csv`` format and dataset readers.

The training-set format
-----------------------
A folder of images plus a ``poses.csv`` with a header row and one row per
image. Columns (order free, names fixed):

=================  ========  ==================================================
column             required  meaning
=================  ========  ==================================================
``image``          yes       image file, relative to the folder
``azimuth_deg``    yes       azimuth of the object, degrees
``elevation_deg``  no        camera elevation, degrees (default 0)
``inplane_deg``    no        in-plane rotation of the image, degrees (default 0)
``box_x``,         no        object box in pixels: left, top, width, height
``box_y``,                   (all four or none; a row with the four empty has
``box_w``,                   none: the mask's box, or the whole image)
``box_h``
``mask``           no        mask image, relative to the folder; non-zero
                             pixels are the object; edges are kept only there
``distance_m``     no        camera distance to the object's reference point,
                             metres (with the training camera, gives the
                             object's metric height: :mod:`posevote.camera`)
``origin_u``,      no        the image of the object's origin (a mesh origin,
``origin_v``                 say), pixels (both or none; in every row): the
                             point ``t_cam_obj`` then names
``instance``       no        instance name (for category models)
``category``       no        category name
=================  ========  ==================================================

The box fixes the object's reference point (its centre) and, with the
instance's median box height, the scale of each training view.

The file is UTF-8 (a byte-order mark is allowed). No other column is read:
an unknown one is refused, with the near column name when there is one, so
that a misspelt optional column is not ignored. Each image has one row;
azimuth and in-plane angles lie within +-720 degrees. Image and mask paths
are relative and stay inside the folder unless ``allow_outside_paths``.
"""

from __future__ import annotations

import csv
import difflib
import io
import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from posevote.camera import Camera, object_height_from_distances
from posevote.data.images import read_image, read_mask

POSES_FILE = "poses.csv"
_BOX_COLUMNS = ("box_x", "box_y", "box_w", "box_h")
_ORIGIN_COLUMNS = ("origin_u", "origin_v")


@dataclass(frozen=True, kw_only=True)
class TrainingSet:
    """Images with their annotated poses, as read from disk.

    Attributes
    ----------
    images : tuple of Path
        Image files.
    poses : ndarray, shape (K, 3)
        Azimuth, elevation and in-plane angle of each image, radians.
    boxes : ndarray, shape (K, 4) or None
        Object boxes ``(x, y, w, h)`` in pixels; NaN rows have no box.
    masks : tuple of (Path or None)
        Mask files, or None per image.
    instances : tuple of str
        Instance name of each image.
    category : str
        Category name ("" when not given).
    distances : ndarray, shape (K,) or (0,)
        Camera distance of each image, metres (NaN where not given; empty
        when the column is absent).
    origins : ndarray, shape (K, 2), (K, 3) or (0, 2)
        The image of the object's origin in each image, pixels, and, from a
        BOP scene, its depth factor (empty when not given): ``fit(...,
        origins=)``. ``poses.csv`` holds the first two.
    """

    images: tuple[Path, ...]
    poses: NDArray[np.float64]
    boxes: NDArray[np.float64]
    masks: tuple[Path | None, ...] = field(default=())
    instances: tuple[str, ...] = field(default=())
    category: str = ""
    distances: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    origins: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))

    def __len__(self) -> int:
        return len(self.images)

    def subset(self, index: Sequence[int] | NDArray[np.integer]) -> TrainingSet:
        """The training set restricted to the given rows."""
        idx = np.asarray(index, dtype=int)
        return TrainingSet(
            images=tuple(self.images[i] for i in idx),
            poses=self.poses[idx],
            boxes=self.boxes[idx],
            masks=tuple(self.masks[i] for i in idx) if self.masks else (),
            instances=tuple(self.instances[i] for i in idx) if self.instances else (),
            category=self.category,
            distances=self.distances[idx] if len(self.distances) else self.distances,
            origins=self.origins[idx] if len(self.origins) else self.origins,
        )

    def object_height_m(self, camera: Camera | Sequence[Camera]) -> float:
        """The object's height in metres from the training camera(s) and ``distances``.

        Raises
        ------
        ValueError
            If a row has no distance or no box (:func:`posevote.camera.object_height_from_distances`).
        """
        if len(self.distances) != len(self) or not np.all(np.isfinite(self.distances)):
            raise ValueError("the object's height from the training camera needs a distance_m "
                             "in every row of poses.csv")
        if not np.all(np.isfinite(self.boxes)):
            raise ValueError("the object's height from distance_m needs the box columns")
        return object_height_from_distances(self.boxes[:, 3], self.distances, camera)

    def load_images(self) -> list[NDArray[np.float64]]:
        """Read every image (grey, float in [0, 1])."""
        return [read_image(p) for p in self.images]

    def load_masks(self) -> list[NDArray[np.bool_] | None]:
        """Read every mask (None where an image has none)."""
        masks = self.masks or (None,) * len(self.images)
        return [None if m is None else read_mask(m) for m in masks]


#: The columns poses.csv may have; any other column is refused (a misspelt
#: optional column would otherwise be ignored without a word).
COLUMNS = ("image", "azimuth_deg", "elevation_deg", "inplane_deg", *_BOX_COLUMNS, "mask",
           "distance_m", *_ORIGIN_COLUMNS, "instance", "category")
#: Azimuth and in-plane angles beyond this (degrees) are refused as mistakes.
MAX_ANGLE_DEG = 720.0
#: A poses.csv larger than this (bytes) is refused before it is read.
MAX_POSES_BYTES = 64 << 20


def _parse_float(text: str, *, path: Path, row: int, column: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(
            f"{path}, row {row}: column {column!r} must be a number, got {text!r}"
        ) from None
    if not math.isfinite(value):
        raise ValueError(f"{path}, row {row}: column {column!r} is {text!r}; expected a finite number")
    return value


def _inside(folder: Path, name: str, *, path: Path, row: int, column: str,
            allow_outside: bool) -> Path:
    """``folder / name``, refused if ``name`` leads outside ``folder`` (unless allowed)."""
    relative = Path(name)
    escapes = relative.is_absolute() or os.path.normpath(name).split(os.sep)[0] == ".."
    hint = "(allow_outside_paths=True, or --allow-outside-paths, to permit it)"
    if escapes and not allow_outside:
        raise ValueError(f"{path}, row {row}: column {column!r} names {name!r}, outside the "
                         f"training folder; paths must be relative and stay inside it {hint}")
    # The rule holds for the real file: a link inside the folder may lead out of it.
    if not allow_outside and not (folder / relative).resolve().is_relative_to(
            folder.resolve()):
        raise ValueError(f"{path}, row {row}: column {column!r} names {name!r}, a link that "
                         f"leads outside the training folder, to "
                         f"{(folder / relative).resolve()} {hint}")
    return folder / relative


def _header(path: Path, fields: list[str]) -> list[str]:
    columns = [c.strip() for c in fields]
    seen: set[str] = set()
    for c in columns:
        if c in seen:
            raise ValueError(f"{path}: column {c!r} appears twice in the header")
        seen.add(c)
    unknown = [c for c in columns if c not in COLUMNS]
    if unknown:
        hints = []
        for c in unknown:
            near = difflib.get_close_matches(c, COLUMNS, n=1, cutoff=0.6)
            hints.append(f"{c!r}" + (f" (did you mean {near[0]!r}?)" if near else ""))
        raise ValueError(f"{path}: unknown column(s) {', '.join(hints)}; the columns are "
                         f"{', '.join(COLUMNS)}")
    for required in ("image", "azimuth_deg"):
        if required not in columns:
            raise ValueError(
                f"{path}: missing column {required!r} (header has {', '.join(columns) or 'nothing'})"
            )
    has_box = [c in columns for c in _BOX_COLUMNS]
    if any(has_box) and not all(has_box):
        raise ValueError(f"{path}: give all four box columns {_BOX_COLUMNS} or none")
    if (_ORIGIN_COLUMNS[0] in columns) != (_ORIGIN_COLUMNS[1] in columns):
        raise ValueError(f"{path}: give both origin columns {_ORIGIN_COLUMNS} or none")
    return columns


def _read_rows(path: Path) -> list[list[str]]:
    """The rows of ``path`` (header first), with errors naming the file and line."""
    size = path.stat().st_size
    if size > MAX_POSES_BYTES:
        raise ValueError(f"{path}: {size:,} bytes, over the limit of {MAX_POSES_BYTES:,} for a "
                         "poses file")
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8-sig")  # a UTF-8 byte-order mark is allowed
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise ValueError(f"{path}, line {line}: not UTF-8 text (byte {exc.start}); save the "
                         "file as UTF-8") from None
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        return [row for row in reader if row and any(cell.strip() for cell in row)]
    except csv.Error as exc:
        raise ValueError(f"{path}, line {reader.line_num}: malformed CSV ({exc})") from None


def read_poses_csv(folder: str | Path, *, allow_outside_paths: bool = False) -> TrainingSet:
    r"""Read a training set folder: images plus ``poses.csv`` (module docstring).

    Parameters
    ----------
    folder : str or Path
        Folder holding ``poses.csv`` and the images it names.
    allow_outside_paths : bool, optional
        Let image and mask paths be absolute or lead out of ``folder``
        (``../``, or a symbolic link to a file or folder elsewhere); refused
        by default, so that a poses file cannot make posevote read files
        elsewhere.

    Returns
    -------
    TrainingSet

    Raises
    ------
    FileNotFoundError
        If the folder, ``poses.csv`` or an image or mask it names is missing.
    ValueError
        If ``poses.csv`` is malformed: unknown, duplicate or missing
        columns, non-numeric, NaN or out-of-range values, a partial or
        non-positive box, two rows for one image, a path leading outside
        the folder, text that is not UTF-8. The message names the row.

    Examples
    --------
    >>> import tempfile, cv2
    >>> from posevote.data import toy_views
    >>> folder = Path(tempfile.mkdtemp())
    >>> images, poses, boxes = toy_views([0, 20])
    >>> for name, image in zip(("a.png", "b.png"), images):
    ...     _ = cv2.imwrite(str(folder / name), (255 * image).astype("uint8"))
    >>> _ = (folder / "poses.csv").write_text(
    ...     "image,azimuth_deg,box_x,box_y,box_w,box_h\n"
    ...     "a.png,0,34,34,61,61\n"
    ...     "b.png,20,33,34,64,61\n")
    >>> training = read_poses_csv(folder)
    >>> len(training), training.poses[:, 0].round(3).tolist()
    (2, [0.0, 0.349])
    """
    folder = Path(folder)
    path = folder / POSES_FILE
    if not folder.is_dir():
        raise FileNotFoundError(f"training folder not found: {folder}")
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: a training folder needs a {POSES_FILE}")
    table = _read_rows(path)
    if not table:
        raise ValueError(f"{path}: the file is empty; it needs a header row and one row per image")
    columns = _header(path, table[0])
    has_box = _BOX_COLUMNS[0] in columns
    has_origin = _ORIGIN_COLUMNS[0] in columns
    origins: list[list[float]] = []
    images: list[Path] = []
    poses: list[NDArray[np.float64]] = []
    boxes: list[list[float]] = []
    masks: list[Path | None] = []
    instances: list[str] = []
    distances: list[float] = []
    categories: set[str] = set()
    first_row: dict[str, int] = {}
    for row_number, cells in enumerate(table[1:], start=2):
        if len(cells) > len(columns):
            raise ValueError(f"{path}, row {row_number}: more fields than header columns "
                             f"({len(cells)} for {len(columns)})")
        if len(cells) < len(columns):
            raise ValueError(f"{path}, row {row_number}: {len(cells)} fields for "
                             f"{len(columns)} header columns")
        row = {c: v.strip() for c, v in zip(columns, cells, strict=True)}
        name = row["image"]
        if not name:
            raise ValueError(f"{path}, row {row_number}: empty 'image'")
        image_path = _inside(folder, name, path=path, row=row_number, column="image",
                             allow_outside=allow_outside_paths)
        # One file under two names (a link) is one image too.
        key = str(image_path.resolve())
        if key in first_row:
            raise ValueError(f"{path}, row {row_number}: image {name!r} is already given in row "
                             f"{first_row[key]}; give each image one row")
        first_row[key] = row_number
        if not image_path.is_file():
            raise FileNotFoundError(f"{path}, row {row_number}: image file not found: {image_path}")
        angles = [
            _parse_float(row.get(col) or ("0" if col != "azimuth_deg" else ""),
                         path=path, row=row_number, column=col)
            for col in ("azimuth_deg", "elevation_deg", "inplane_deg")
        ]
        if abs(angles[1]) > 90:
            raise ValueError(f"{path}, row {row_number}: elevation_deg must be in [-90, 90], "
                             f"got {angles[1]}")
        for col, value in (("azimuth_deg", angles[0]), ("inplane_deg", angles[2])):
            if abs(value) > MAX_ANGLE_DEG:
                raise ValueError(f"{path}, row {row_number}: {col} must be in "
                                 f"[-{MAX_ANGLE_DEG:g}, {MAX_ANGLE_DEG:g}] degrees, got {value:g}")
        poses.append(np.radians(angles))
        if has_box and any(row[c] for c in _BOX_COLUMNS):
            box = [_parse_float(row[c], path=path, row=row_number, column=c)
                   for c in _BOX_COLUMNS]
            if box[2] <= 0 or box[3] <= 0:
                raise ValueError(f"{path}, row {row_number}: box width and height must be "
                                 f"positive, got {box[2]} x {box[3]}")
            boxes.append(box)
        else:
            boxes.append([np.nan] * 4)
        mask_name = row.get("mask", "")
        if mask_name:
            mask_path = _inside(folder, mask_name, path=path, row=row_number, column="mask",
                                allow_outside=allow_outside_paths)
            if not mask_path.is_file():
                raise FileNotFoundError(f"{path}, row {row_number}: mask file not found: {mask_path}")
            masks.append(mask_path)
        else:
            masks.append(None)
        if row.get("distance_m"):
            distance = _parse_float(row["distance_m"], path=path, row=row_number,
                                    column="distance_m")
            if not 0 < distance < 1e5:
                raise ValueError(f"{path}, row {row_number}: distance_m must be a positive "
                                 f"number of metres, got {distance:g}")
            distances.append(distance)
        else:
            distances.append(np.nan)
        if has_origin:
            origins.append([_parse_float(row[c], path=path, row=row_number, column=c)
                            for c in _ORIGIN_COLUMNS])
        instances.append(row.get("instance", ""))
        if row.get("category"):
            categories.add(row["category"])
        images.append(image_path)
    if not images:
        raise ValueError(f"{path}: no rows; a training set needs at least one image")
    named = [bool(i) for i in instances]
    if any(named) and not all(named):
        empty = named.index(False) + 2
        raise ValueError(f"{path}, row {empty}: the instance column is empty here and filled "
                         "in other rows; name every row's instance, or none")
    if len(categories) > 1:
        raise ValueError(f"{path}: rows name several categories ({sorted(categories)}); "
                         "train one model per category")
    return TrainingSet(
        images=tuple(images),
        poses=np.array(poses),
        boxes=np.array(boxes, dtype=np.float64),
        masks=tuple(masks),
        instances=tuple(instances),
        category=categories.pop() if categories else "",
        distances=np.array(distances) if "distance_m" in columns else np.zeros(0),
        origins=np.array(origins, dtype=np.float64).reshape(-1, 2),
    )


def write_poses_csv(training_set: TrainingSet, folder: str | Path) -> Path:
    """Write ``poses.csv`` for a training set whose images lie in ``folder``.

    Image and mask paths are written relative to ``folder``. The file is
    written atomically.
    """
    from posevote._io import atomic_write_text

    folder = Path(folder)
    origins = len(training_set.origins) == len(training_set) > 0
    lines = ["image,azimuth_deg,elevation_deg,inplane_deg,box_x,box_y,box_w,box_h,mask,"
             "distance_m," + ("origin_u,origin_v," if origins else "") + "instance,category"]
    masks = training_set.masks or (None,) * len(training_set)
    instances = training_set.instances or ("",) * len(training_set)
    distances = training_set.distances if len(training_set.distances) \
        else np.full(len(training_set), np.nan)
    for k, (img, pose, box, mask, dist, inst) in enumerate(zip(
            training_set.images, training_set.poses, training_set.boxes, masks, distances,
            instances, strict=True)):
        box_text = ",".join("" if np.isnan(b) else f"{b:.3f}" for b in box)
        deg = np.degrees(pose)
        rel = Path(img).resolve().relative_to(folder.resolve())
        mask_text = "" if mask is None else str(Path(mask).resolve().relative_to(folder.resolve()))
        dist_text = "" if np.isnan(dist) else f"{dist:.6g}"
        origin_text = "".join(f"{c:.3f}," for c in training_set.origins[k, :2]) if origins \
            else ""
        lines.append(f"{rel},{deg[0]:.4f},{deg[1]:.4f},{deg[2]:.4f},{box_text},{mask_text},"
                     f"{dist_text},{origin_text}{inst},{training_set.category}")
    out = folder / POSES_FILE
    atomic_write_text(out, "\n".join(lines) + "\n")
    return out


# --- COIL-100 ---------------------------------------------------------------

_COIL_NAME = re.compile(r"^obj(\d+)__(\d+)\.png$")


def object_mask(image: NDArray[np.float64], *, margin: float = 0.05) -> NDArray[np.bool_]:
    """Pixels of an object photographed on a dark, uniform background (COIL-100).

    The background level is the median of the image border; pixels brighter
    than it by ``margin`` belong to the object, after an opening removes
    isolated noisy pixels and small holes are filled.
    """
    from scipy import ndimage

    border = np.concatenate([image[0], image[-1], image[:, 0], image[:, -1]])
    mask = image > float(np.median(border)) + margin
    opened = ndimage.binary_opening(mask, iterations=1)
    mask = opened if opened.any() else mask
    return ndimage.binary_fill_holes(ndimage.binary_closing(mask, iterations=2))


def object_box(image: NDArray[np.float64], *, margin: float = 0.05) -> NDArray[np.float64]:
    """Box ``(x, y, w, h)`` of :func:`object_mask` (the whole image if it is empty)."""
    mask = object_mask(image, margin=margin)
    if not mask.any():
        return np.array([0.0, 0.0, image.shape[1], image.shape[0]])
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    return np.array([cols[0], rows[0], cols[-1] - cols[0] + 1, rows[-1] - rows[0] + 1], dtype=float)


def read_coil(folder: str | Path, *, objects: Sequence[int],
              azimuths_deg: ArrayLike | None = None, category: str = "") -> TrainingSet:
    """COIL-100 views as a training set (files ``objN__A.png``, A in degrees).

    The box of each view is found by thresholding the dark background
    (:func:`object_mask`).

    Parameters
    ----------
    folder : str or Path
        The COIL-100 folder.
    objects : sequence of int
        Object numbers to read; each becomes an instance ``objN``.
    azimuths_deg : sequence of float, optional
        Only views at these azimuths (all 72 by default).
    category : str, optional
        Category name to record.

    Returns
    -------
    TrainingSet
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"COIL-100 folder not found: {folder}")
    wanted = None if azimuths_deg is None else {
        round(float(a)) % 360 for a in np.atleast_1d(np.asarray(azimuths_deg, dtype=float))}
    found: dict[int, list[tuple[int, Path]]] = {}
    for p in folder.iterdir():
        m = _COIL_NAME.match(p.name)
        if m:
            found.setdefault(int(m.group(1)), []).append((int(m.group(2)), p))
    images, poses, boxes, instances = [], [], [], []
    for obj in objects:
        if obj not in found:
            raise FileNotFoundError(f"{folder}: no views of object {obj} (files obj{obj}__A.png)")
        for az, p in sorted(found[obj]):
            if wanted is not None and az % 360 not in wanted:
                continue
            images.append(p)
            poses.append([math.radians(az), 0.0, 0.0])
            boxes.append(object_box(read_image(p)))
            instances.append(f"obj{obj}")
    if not images:
        raise ValueError(f"{folder}: no views match objects {list(objects)} and the azimuths asked for")
    return TrainingSet(images=tuple(images), poses=np.array(poses), boxes=np.array(boxes),
                       masks=(None,) * len(images), instances=tuple(instances), category=category)


# --- EPFL Multi-View Car ------------------------------------------------------

def _epfl_path(folder: Path, meta: Path, pattern: str, values: tuple[int, ...]) -> Path:
    """A file named by a pattern of ``tripod-seq.txt``, kept inside ``folder``."""
    try:
        name = pattern % values
    except (TypeError, ValueError):
        raise ValueError(f"{meta}: the file pattern {pattern!r} does not take "
                         f"{len(values)} number(s)") from None
    if Path(name).is_absolute() or os.path.normpath(name).split(os.sep)[0] == "..":
        raise ValueError(f"{meta}: the file pattern {pattern!r} leads outside {folder}")
    return folder / name


def read_epfl(folder: str | Path, *, cars: Sequence[int]) -> TrainingSet:
    """EPFL Multi-View Car (tripod-seq) sequences as a training set.

    Azimuth of frame ``j`` (1-based) of a sequence, from ``tripod-seq.txt``
    (line 5: frame closing the full turn, line 6: frontal frame, line 7:
    rotation sense) and ``times.txt`` (capture time of each frame, seconds)::

        az_j = (dir * (t_j - t_front) * 360 / t_n360) mod 360

    Times are whole seconds, so labels carry 1-2 degrees of noise.

    Parameters
    ----------
    folder : str or Path
        The ``tripod-seq`` folder.
    cars : sequence of int
        Car (sequence) numbers, 1-based.

    Returns
    -------
    TrainingSet
        One instance per car (``car01`` ...), category ``car``.
    """
    folder = Path(folder)
    meta_path = folder / "tripod-seq.txt"
    times_path = folder / "times.txt"
    for p in (meta_path, times_path):
        if not p.is_file():
            raise FileNotFoundError(f"EPFL metadata file not found: {p}")
    meta = meta_path.read_text().splitlines()
    try:
        n_frames = [int(x) for x in meta[1].split()]
        name_pattern = meta[2].strip()
        bbox_pattern = meta[3].strip()
        n360 = [int(x) for x in meta[4].split()]
        front = [int(x) for x in meta[5].split()]
        sense = [int(x) for x in meta[6].split()]
    except (IndexError, ValueError):
        raise ValueError(f"{meta_path}: malformed; expected 7 lines (see METHOD.md)") from None
    if k_lines := {len(n_frames), len(n360), len(front), len(sense)} - {len(n_frames)}:
        raise ValueError(f"{meta_path}: lines 2 and 5-7 must give one number per sequence "
                         f"({len(n_frames)} sequences, other lengths {sorted(k_lines)})")
    try:
        times = [[float(x) for x in line.split()] for line in times_path.read_text().splitlines()]
    except (ValueError, UnicodeDecodeError):
        raise ValueError(f"{times_path}: malformed; expected one line of frame times (seconds) "
                         "per sequence") from None
    images, poses, boxes, instances = [], [], [], []
    for car in cars:
        if not 1 <= car <= len(n_frames):
            raise ValueError(f"car {car} is not in {meta_path} (1..{len(n_frames)})")
        k = car - 1
        t = np.array(times[k] if k < len(times) else [])
        if len(t) != n_frames[k]:
            raise ValueError(f"{times_path}, line {car}: {len(t)} times for {n_frames[k]} frames")
        bbox_path = _epfl_path(folder, meta_path, bbox_pattern, (car,))
        if not bbox_path.is_file():
            raise FileNotFoundError(f"EPFL box file not found: {bbox_path}")
        try:
            bb = np.loadtxt(bbox_path, ndmin=2)
        except ValueError:
            raise ValueError(f"{bbox_path}: malformed; expected rows of x y w h") from None
        if bb.shape != (n_frames[k], 4):
            raise ValueError(f"{bbox_path}: expected {n_frames[k]} rows of x y w h, got {bb.shape}")
        if not (1 <= front[k] <= n_frames[k] and 2 <= n360[k] <= n_frames[k]):
            raise ValueError(f"{meta_path}: sequence {car}'s frontal frame {front[k]} or "
                             f"full-turn frame {n360[k]} is not among its {n_frames[k]} frames")
        t_front = t[front[k] - 1]
        t_360 = t[n360[k] - 1] - t[0]
        for j in range(n_frames[k]):
            img = _epfl_path(folder, meta_path, name_pattern, (car, j + 1))
            if not img.is_file():
                raise FileNotFoundError(f"EPFL image not found: {img}")
            az = (sense[k] * (t[j] - t_front) * 360.0 / t_360) % 360.0
            images.append(img)
            poses.append([math.radians(az), 0.0, 0.0])
            boxes.append(bb[j])
            instances.append(f"car{car:02d}")
    return TrainingSet(images=tuple(images), poses=np.array(poses), boxes=np.array(boxes),
                       masks=(None,) * len(images), instances=tuple(instances), category="car")
