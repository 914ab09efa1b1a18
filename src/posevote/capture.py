"""Training views from photographs of an object standing on a printed ChArUco board.

The board (:func:`write_board`) is printed and the object stood on it; the
photographs are taken from around it, by hand or by a robot. Each photograph
shows the board's ChArUco corners, and so the camera's pose relative to the
board (OpenCV's ``cv2.aruco``); with the object's footprint on the board
(:class:`Footprint`: where it stands, its radius and height) that is the
object's pose, and the cylinder's outline on the image holds the object:
:func:`object_mask` cuts it out (GrabCut, told what the board's squares look
like there). :func:`capture` calibrates the camera from the same photographs
(or takes a given one), writes each usable photograph undistorted with its
pose, the mask's box, its mask and the image of the object's reference point
to ``poses.csv``, writes ``camera.json``, and names every photograph it
refuses and why.

Frames. The board's frame is OpenCV's: origin at the printed board's
top-left chessboard corner, ``x`` along its width (to the right as printed),
``y`` down the print, ``z`` into the board. The object's frame
(:mod:`posevote.geometry`) stands on the footprint's centre: ``+z`` up out
of the printed face, ``+x`` along the board's ``x``. Azimuth 0 therefore has
the camera on the side of the board's right edge (as printed), and the
elevation is the camera's height above the board's plane. The object's
reference point, whose depth is written as ``distance_m`` and image as
``origin_u``, ``origin_v`` (so that an estimate's ``t_cam_obj`` names it), is
the footprint's centre raised by half the object's height.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from posevote._io import atomic_write_text, parse_json
from posevote.camera import Camera
from posevote.geometry import pose_from_rotation

#: The object's axes in the board's frame: x along the board, up out of its printed face.
R_BOARD_OBJ = np.diag([1.0, -1.0, -1.0])

#: Corners a photograph must show for its pose (OpenCV's pose needs four; six steady it).
MIN_CORNERS = 6

#: Photographs the calibration needs (OpenCV's needs three views of the plane).
MIN_CALIBRATION_VIEWS = 4

#: Points around the footprint's rim that the box is projected from.
_RIM_POINTS = 72

#: The training folder's sub-folder of masks.
_MASKS = "masks"


@dataclass(frozen=True, kw_only=True)
class BoardSpec:
    """A ChArUco board's geometry (what :func:`write_board` records beside the image).

    Attributes
    ----------
    squares : (int, int)
        Chessboard squares across and down.
    square_m : float
        Side of a chessboard square as printed, metres.
    marker_m : float
        Side of an ArUco marker as printed, metres.
    dictionary : str
        The ``cv2.aruco`` dictionary's name.
    """

    squares: tuple[int, int] = (7, 5)
    square_m: float = 0.04
    marker_m: float = 0.03
    dictionary: str = "DICT_5X5_100"

    def __post_init__(self) -> None:
        sx, sy = (int(v) for v in self.squares)
        if not (3 <= sx <= 40 and 3 <= sy <= 40):
            raise ValueError(f"BoardSpec.squares must be two numbers from 3 to 40, got "
                             f"{self.squares!r}")
        object.__setattr__(self, "squares", (sx, sy))
        if not (math.isfinite(self.square_m) and 0.002 <= self.square_m <= 1.0):
            raise ValueError(f"BoardSpec.square_m must be 2 mm to 1 m, got {self.square_m!r}")
        if not (math.isfinite(self.marker_m) and 0.0 < self.marker_m < self.square_m):
            raise ValueError(f"BoardSpec.marker_m must be positive and under square_m, got "
                             f"{self.marker_m!r}")
        if not self.dictionary.startswith("DICT_") or not hasattr(cv2.aruco, self.dictionary):
            raise ValueError(f"BoardSpec.dictionary must name a cv2.aruco dictionary, got "
                             f"{self.dictionary!r}")

    def board(self) -> Any:
        """The ``cv2.aruco.CharucoBoard``."""
        words = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard(self.squares, self.square_m, self.marker_m, words)

    @property
    def size_m(self) -> tuple[float, float]:
        """The board's width and height, metres."""
        return self.squares[0] * self.square_m, self.squares[1] * self.square_m

    @classmethod
    def read(cls, path: str | Path) -> BoardSpec:
        """A board file written by :func:`write_board` (the message names the file)."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"board file not found: {path}")
        if path.stat().st_size > 1 << 16:
            raise ValueError(f"{path}: too large for a board file")
        data = parse_json(path.read_text(encoding="utf-8"), str(path))
        if not isinstance(data, dict) or set(data) - {"squares", "square_m", "marker_m",
                                                      "dictionary", "dpi"}:
            raise ValueError(f"{path}: expected squares, square_m, marker_m, dictionary")
        try:
            return cls(squares=tuple(data["squares"]), square_m=float(data["square_m"]),
                       marker_m=float(data["marker_m"]), dictionary=str(data["dictionary"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{path}: {exc}") from None


@dataclass(frozen=True, kw_only=True)
class Footprint:
    """Where the object stands on the board and the cylinder that bounds it.

    Attributes
    ----------
    centre_m : (float, float)
        Its centre in the board's frame (metres from the top-left chessboard
        corner, ``x`` right, ``y`` down the print).
    radius_m, height_m : float
        The bounding cylinder's radius and height, metres.
    """

    centre_m: tuple[float, float]
    radius_m: float
    height_m: float

    def __post_init__(self) -> None:
        for name in ("radius_m", "height_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.001 <= value <= 10.0):
                raise ValueError(f"Footprint.{name} must be 1 mm to 10 m, got {value!r}")
        x, y = (float(v) for v in self.centre_m)
        if not (math.isfinite(x) and math.isfinite(y) and abs(x) <= 10 and abs(y) <= 10):
            raise ValueError(f"Footprint.centre_m must be within 10 m of the board, got "
                             f"{self.centre_m!r}")
        object.__setattr__(self, "centre_m", (x, y))

    def reference_point(self) -> NDArray[np.float64]:
        """The object's reference point in the board's frame (half its height up)."""
        return np.array([self.centre_m[0], self.centre_m[1], -self.height_m / 2.0])

    def rim(self) -> NDArray[np.float64]:
        """Points on the bounding cylinder's bottom and top circles, board frame."""
        a = np.linspace(0.0, 2.0 * np.pi, _RIM_POINTS, endpoint=False)
        ring = np.column_stack([self.centre_m[0] + self.radius_m * np.cos(a),
                                self.centre_m[1] + self.radius_m * np.sin(a)])
        return np.vstack([np.column_stack([ring, np.zeros(len(a))]),
                          np.column_stack([ring, np.full(len(a), -self.height_m)])])


def write_board(path: str | Path, spec: BoardSpec = BoardSpec(), *, dpi: int = 300) -> Path:
    """Write the board's image at ``dpi`` (PNG, to print at 100%) and its geometry beside it
    (``<name>.json``); returns the geometry file's path."""
    path = Path(path)
    if not 72 <= dpi <= 1200:
        raise ValueError(f"dpi must be 72 to 1200, got {dpi}")
    width_m, height_m = spec.size_m
    margin = int(round(0.01 / 0.0254 * dpi))          # a 1 cm white margin
    size = (int(round(width_m / 0.0254 * dpi)) + 2 * margin,
            int(round(height_m / 0.0254 * dpi)) + 2 * margin)
    if size[0] * size[1] > 200_000_000:
        raise ValueError(f"a board of {width_m:.2f} x {height_m:.2f} m at {dpi} dpi is too large")
    image = spec.board().generateImage(size, marginSize=margin)
    from posevote.evaluation.plots import write_png

    write_png(path, np.asarray(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR), dtype=np.uint8))
    geometry = path.with_suffix(".json")
    atomic_write_text(geometry, json.dumps({**asdict(spec), "dpi": dpi}, indent=2) + "\n")
    return geometry


def detect(image: NDArray[np.uint8], spec: BoardSpec
           ) -> tuple[NDArray[np.float32], NDArray[np.float32]] | None:
    """The board's corners a grey photograph shows: their board points (metres) and image
    points, or None when fewer than :data:`MIN_CORNERS` are found."""
    board = spec.board()
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(image)
    if ids is None or len(ids) < MIN_CORNERS:
        return None
    object_points, image_points = board.matchImagePoints(corners, ids)
    return (np.asarray(object_points, np.float32).reshape(-1, 3),
            np.asarray(image_points, np.float32).reshape(-1, 2))


def calibrate(views: Sequence[tuple[NDArray[np.float32], NDArray[np.float32]]],
              image_size: tuple[int, int]) -> tuple[Camera, float]:
    """The camera (intrinsics and k1, k2, p1, p2, k3) from the board's corners in several
    photographs of one size ``(width, height)``, and the RMS reprojection error in pixels."""
    if len(views) < MIN_CALIBRATION_VIEWS:
        raise ValueError(f"calibrating the camera needs the board in at least "
                         f"{MIN_CALIBRATION_VIEWS} photographs, {len(views)} show it; give a "
                         "camera file instead")
    # k3 stays 0: a few views of one plane cannot tell it from the focal length.
    rms, K, dist, _, _ = cv2.calibrateCamera([v[0] for v in views], [v[1] for v in views],
                                             image_size, None, None,
                                             flags=cv2.CALIB_FIX_K3)
    return Camera(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2],
                  dist=tuple(float(d) for d in np.ravel(dist)[:5])), float(rms)


def _board_as_background(photo: NDArray[np.uint8], board: NDArray[np.float64],
                         label: NDArray[np.uint8]) -> None:
    """Mark the outline's pixels that look as the board there as probably the background."""
    colour = cv2.GaussianBlur(photo.astype(np.float64) / 255.0, (0, 0), 1.0)
    grey = np.asarray(cv2.cvtColor(photo, cv2.COLOR_BGR2GRAY), dtype=np.float64) / 255.0
    on = np.isfinite(board)
    ring = on & (label == cv2.GC_BGD)
    if np.count_nonzero(ring) < 50:
        return
    # The print's ink and paper as this photograph renders them: a line fit on the ring.
    slope, offset = np.polyfit(board[ring], grey[ring], 1)
    if slope <= 0.05:
        return
    expected = cv2.GaussianBlur(np.where(on, board, 0.5), (0, 0), 1.0) * slope + offset
    # Either test marks a pixel (each alone left squares in the cut on some of the rendered
    # photographs: docs/history/CAPTURE.md). The print is grey: a coloured pixel is not it.
    loose = np.abs(colour - expected[..., None]).max(axis=2) < 0.25 * slope
    # Or its grey level is the board's, as is its neighbourhood's (the squares' edges move a
    # pixel with the pose).
    near = cv2.dilate(np.abs(cv2.GaussianBlur(grey, (0, 0), 1.0) - expected), np.ones((3, 3)))
    strict = (np.abs(grey - expected) < 0.15 * slope) & (near < 0.3 * slope)
    label[on & (loose | strict) & (label == cv2.GC_PR_FGD)] = cv2.GC_PR_BGD


def board_pose(view: tuple[NDArray[np.float32], NDArray[np.float32]], camera: Camera
               ) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """``R_cam_board``, ``t_cam_board`` (metres) and the RMS reprojection error (pixels) of
    one photograph's corners, seen through ``camera``."""
    points, pixels = view
    dist = np.asarray(camera.dist, dtype=np.float64) if camera.dist else None
    ok, rvec, tvec = cv2.solvePnP(points, pixels, camera.K, dist)
    if not ok:
        raise ValueError("the board's pose could not be solved")
    projected, _ = cv2.projectPoints(points, rvec, tvec, camera.K, dist)
    error = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - pixels) ** 2, axis=1))))
    rotation = np.asarray(cv2.Rodrigues(rvec)[0], dtype=np.float64)
    return rotation, np.asarray(tvec, dtype=np.float64).reshape(3), error


def object_pose(R_cam_board: NDArray[np.float64], t_cam_board: NDArray[np.float64],
                footprint: Footprint) -> tuple[float, float, float, NDArray[np.float64]]:
    """The object's azimuth, elevation, in-plane angle (radians) and reference point in the
    camera frame (metres), from the board's pose."""
    azimuth, elevation, inplane = pose_from_rotation(R_cam_board @ R_BOARD_OBJ)
    return azimuth, elevation, inplane, R_cam_board @ footprint.reference_point() + t_cam_board


def outline(R_cam_board: NDArray[np.float64], t_cam_board: NDArray[np.float64],
            footprint: Footprint, camera: Camera) -> NDArray[np.float64]:
    """The footprint's cylinder as the undistorted camera sees it: the image of its rim,
    ``(N, 2)`` pixels."""
    rim = footprint.rim() @ R_cam_board.T + t_cam_board
    if np.any(rim[:, 2] <= 0):
        raise ValueError("the object is not in front of the camera")
    return np.column_stack([camera.fx * rim[:, 0] / rim[:, 2] + camera.cx,
                            camera.fy * rim[:, 1] / rim[:, 2] + camera.cy])


def object_box(R_cam_board: NDArray[np.float64], t_cam_board: NDArray[np.float64],
               footprint: Footprint, camera: Camera) -> tuple[float, float, float, float]:
    """The box ``(x, y, w, h)`` of the footprint's cylinder as the undistorted camera sees it."""
    uv = outline(R_cam_board, t_cam_board, footprint, camera)
    (x0, y0), (x1, y1) = uv.min(axis=0), uv.max(axis=0)
    return float(x0), float(y0), float(x1 - x0), float(y1 - y0)


@cache
def squares_image(spec: BoardSpec, ppm: float) -> NDArray[np.float32]:
    """The board's squares at ``ppm`` pixels per metre, grey levels in ``[0, 1]`` (made once
    per board: every photograph's view warps it)."""
    size = (int(spec.size_m[0] * ppm), int(spec.size_m[1] * ppm))
    image = spec.board().generateImage(size, marginSize=0).astype(np.float32) / 255.0
    image.setflags(write=False)
    return image


def board_view(spec: BoardSpec, R_cam_board: NDArray[np.float64],
               t_cam_board: NDArray[np.float64], camera: Camera, size: tuple[int, int]
               ) -> NDArray[np.float64]:
    """The printed squares as the undistorted camera sees them: grey levels in ``[0, 1]``,
    NaN off the squares; ``size`` is the photograph's ``(width, height)``."""
    ppm = 2000.0   # board pixels per metre: 2 mm squares' detail at 0.5 mm
    squares = squares_image(spec, ppm)
    H = camera.K @ np.column_stack([R_cam_board[:, 0], R_cam_board[:, 1], t_cam_board]) \
        @ np.diag([1.0 / ppm, 1.0 / ppm, 1.0])
    seen = cv2.warpPerspective(squares, H, size, flags=cv2.INTER_AREA, borderValue=np.nan)
    return np.asarray(seen, dtype=np.float64)


def object_mask(photo: NDArray[np.uint8], rim: NDArray[np.float64],
                board: NDArray[np.float64] | None = None) -> NDArray[np.bool_] | None:
    """The object's pixels in an (undistorted, BGR) photograph, within the image ``rim`` of its
    footprint's cylinder (:func:`outline`).

    GrabCut, started with the cylinder's outline as probably the object, the ring around it
    as the background and, given the board as the camera sees it (:func:`board_view`), the
    outline's pixels that look as the board there as probably the background. None when the
    cut keeps less than a twentieth of the outline (nothing there to tell from the board).
    """
    h, w = photo.shape[:2]
    hull = cv2.convexHull(np.round(rim).astype(np.int32))
    (x0, y0), (x1, y1) = rim.min(axis=0), rim.max(axis=0)
    # The ring: a quarter of the outline's size all round, whose colours are the background's.
    pad = 0.25 * max(x1 - x0, y1 - y0)
    c0, r0 = max(int(x0 - pad), 0), max(int(y0 - pad), 0)
    c1, r1 = min(int(np.ceil(x1 + pad)) + 1, w), min(int(np.ceil(y1 + pad)) + 1, h)
    start = np.full((r1 - r0, c1 - c0), cv2.GC_BGD, np.uint8)
    cv2.fillConvexPoly(start, hull - np.array([c0, r0], np.int32), int(cv2.GC_PR_FGD))
    inside = int(np.count_nonzero(start == cv2.GC_PR_FGD))
    if inside < 16 or inside == start.size:
        return None
    if board is not None:
        _board_as_background(photo[r0:r1, c0:c1], board[r0:r1, c0:c1], start)
        if np.count_nonzero(start == cv2.GC_PR_FGD) < inside / 20:
            return None   # the outline shows the board: nothing stands there
    label = start.copy()
    background, foreground = np.zeros((1, 65)), np.zeros((1, 65))
    cv2.setRNGSeed(0)   # GrabCut's k-means draws from OpenCV's RNG: the same photo, the same cut
    cv2.grabCut(np.ascontiguousarray(photo[r0:r1, c0:c1]), label, None,  # type: ignore[call-overload]
                background, foreground, 5, cv2.GC_INIT_WITH_MASK)
    cut = np.asarray((label == cv2.GC_FGD) | (label == cv2.GC_PR_FGD), dtype=np.uint8)
    count, parts, stats, _ = cv2.connectedComponentsWithStats(cut, connectivity=8)
    if count < 2:
        return None
    # The largest part, its holes filled: pieces of the board's squares cut apart are dropped.
    keep = parts == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    outside = np.pad(~keep, 1, constant_values=True).astype(np.uint8)
    cv2.floodFill(outside, None, (0, 0), 2)
    keep |= outside[1:-1, 1:-1] == 1
    if np.count_nonzero(keep) < inside / 20:
        return None
    mask = np.zeros((h, w), bool)
    mask[r0:r1, c0:c1] = keep
    return mask


@dataclass(frozen=True)
class CaptureReport:
    """What :func:`capture` wrote and refused.

    Attributes
    ----------
    camera : Camera
        The camera (calibrated, or given).
    calibration_rms_px : float or None
        The calibration's RMS reprojection error (None: the camera was given).
    kept : list of dict
        Per written photograph: its name, azimuth, elevation, in-plane angle (degrees),
        box, whether it has a mask, distance (metres), origin (pixels) and reprojection
        error.
    refused : list of (str, str)
        Per refused photograph: its name and why.
    """

    camera: Camera
    calibration_rms_px: float | None
    kept: list[dict[str, Any]] = field(default_factory=list)
    refused: list[tuple[str, str]] = field(default_factory=list)


def capture(photos: Sequence[str | Path], out: str | Path, *, footprint: Footprint,
            spec: BoardSpec = BoardSpec(), camera: Camera | None = None,
            max_error_px: float = 1.5,
            progress: Callable[[int], None] | None = None) -> CaptureReport:
    """A training folder from photographs of the object on the board (the module docstring).

    Parameters
    ----------
    photos : sequence of path
        The photographs (one camera, one image size).
    out : path
        The training folder to write: the usable photographs undistorted (PNG),
        their masks (``masks/``), ``poses.csv`` (image, azimuth, elevation,
        in-plane angle, box, mask, distance, origin) and ``camera.json`` (the
        camera, with its distortion). Where no mask can be cut, the row has the
        cylinder's box and no mask.
    footprint : Footprint
    spec : BoardSpec, optional
        The printed board (:meth:`BoardSpec.read` of the file :func:`write_board` wrote).
    camera : Camera, optional
        The camera; None: calibrated from the photographs themselves.
    max_error_px : float, optional
        A photograph whose corners reproject worse than this (RMS, pixels) is refused.
    progress : callable, optional
        Called with 1 after each photograph is read.

    Returns
    -------
    CaptureReport

    Raises
    ------
    ValueError
        When the photographs differ in size, too few show the board, or none is kept.
    """
    from posevote.data import read_bgr8
    from posevote.data.training_set import TrainingSet, write_poses_csv

    if not 0.1 <= max_error_px <= 20:
        raise ValueError(f"max_error_px must be 0.1 to 20 pixels, got {max_error_px}")
    out = Path(out)
    if any(Path(p).resolve().parent == out.resolve() for p in photos):
        raise ValueError(f"{out}: holds the photographs themselves; write the training "
                         "folder elsewhere")
    seen: list[tuple[Path, NDArray[np.uint8], tuple[Any, Any] | None]] = []
    size: tuple[int, int] | None = None
    for photo in map(Path, photos):
        image = read_bgr8(photo)
        if size is None:
            size = (image.shape[1], image.shape[0])
        elif (image.shape[1], image.shape[0]) != size:
            raise ValueError(f"{photo}: {image.shape[1]} x {image.shape[0]} pixels, the others "
                             f"{size[0]} x {size[1]}; give photographs of one camera and size")
        grey = np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), dtype=np.uint8)
        seen.append((photo, image, detect(grey, spec)))
        if progress is not None:
            progress(1)
    if size is None:
        raise ValueError("no photograph given")
    refused = [(str(p), f"the board is not found (fewer than {MIN_CORNERS} corners)")
               for p, _, v in seen if v is None]
    views = [(p, img, v) for p, img, v in seen if v is not None]
    rms = None
    if camera is None:
        camera, rms = calibrate([v for _, _, v in views], size)
    plain = Camera(fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy)
    rows: list[dict[str, Any]] = []
    images: list[tuple[str, NDArray[np.uint8], NDArray[np.bool_] | None]] = []
    for photo, image, view in views:
        R, t, error = board_pose(view, camera)
        if error > max_error_px:
            refused.append((str(photo), f"the board's corners reproject {error:.2f} px off "
                                        f"(over {max_error_px:g} px): the pose is unreliable"))
            continue
        azimuth, elevation, inplane, point = object_pose(R, t, footprint)
        rim = outline(R, t, footprint, plain)
        (x0, y0), (x1, y1) = rim.min(axis=0), rim.max(axis=0)
        if x0 < 0 or y0 < 0 or x1 > size[0] or y1 > size[1]:
            refused.append((str(photo), "the object's box leaves the photograph"))
            continue
        name = f"{photo.stem}.png"
        if any(name == n for n, _, _ in images):
            name = f"{photo.stem}_{len(images)}.png"
        undistorted = np.round(np.clip(camera.undistort(image.astype(np.float64)), 0, 255)
                               ).astype(np.uint8)
        mask = object_mask(undistorted, rim, board_view(spec, R, t, plain, size))
        if mask is None:
            box = (float(x0), float(y0), float(x1 - x0), float(y1 - y0))
        else:
            rr, cc = np.nonzero(mask)
            box = (float(cc.min()), float(rr.min()), float(np.ptp(cc) + 1), float(np.ptp(rr) + 1))
        images.append((name, undistorted, mask))
        rows.append({"image": name, "azimuth_deg": math.degrees(azimuth),
                     "elevation_deg": math.degrees(elevation),
                     "inplane_deg": math.degrees(inplane), "box": box,
                     "mask": mask is not None, "distance_m": float(point[2]),
                     "origin": (float(plain.fx * point[0] / point[2] + plain.cx),
                                float(plain.fy * point[1] / point[2] + plain.cy)),
                     "error_px": error})
    if not rows:
        raise ValueError("no photograph could be used: " + "; ".join(f"{p}: {why}"
                                                                     for p, why in refused))
    out.mkdir(parents=True, exist_ok=True)
    from posevote.evaluation.plots import write_png

    masks: list[Path | None] = []
    for name, image, mask in images:
        write_png(out / name, image)
        masks.append(None if mask is None else out / _MASKS / name)
        if mask is not None:
            (out / _MASKS).mkdir(exist_ok=True)
            write_png(out / _MASKS / name, mask.astype(np.uint8) * 255)
    write_poses_csv(TrainingSet(
        images=tuple(out / r["image"] for r in rows),
        poses=np.radians([[r["azimuth_deg"], r["elevation_deg"], r["inplane_deg"]]
                          for r in rows]),
        boxes=np.array([r["box"] for r in rows]), masks=tuple(masks),
        distances=np.array([r["distance_m"] for r in rows]),
        origins=np.array([r["origin"] for r in rows])), out)
    atomic_write_text(out / "camera.json", json.dumps(camera.to_dict(), indent=2) + "\n")
    return CaptureReport(camera=camera, calibration_rms_px=rms, kept=rows, refused=refused)
