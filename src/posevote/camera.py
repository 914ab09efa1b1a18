"""The camera: from an image-space pose to the object's pose in the camera frame.

posevote estimates an image-space pose: viewpoint, in-plane angle, scale
and the image position of the object's reference point (its box centre).
With the camera's intrinsics and the object's metric size it becomes the
rigid transform ``T_cam_obj`` (frames as in :mod:`posevote.geometry`):

* ``R_cam_obj`` is :func:`posevote.geometry.rotation_from_pose`;
* the depth of the reference point is ``fy * H / (scale * R)``, with ``H``
  the object's height in metres (``object_height_m``, learnt at training)
  and ``R`` the model's reference box height in pixels (an object at scale
  1 appears ``R`` pixels high);
* ``t_cam_obj`` is the reference point's ray scaled to that depth, or,
  when training gave the object's origin in each view (``fit(...,
  origins=)``; BOP scenes do), the ray through the origin's image: each
  view's offset of the origin from the box centre, averaged over the views
  near the estimated viewpoint as the box is, turned and scaled with the
  hypothesis (:func:`posevote.model.density.origin_offset`); with each
  view's depth factor too (BOP scenes give it), at the origin's depth.

``H`` comes from the training set: a known object height, or the training
camera with each training view's distance (``distance_m``), as the median
over the views of ``box height * distance / fy``
(:func:`object_height_from_distances`). For a category model it is the
typical instance's height, so a smaller instance is placed farther away.

A camera file is JSON: ``{"fx": ..., "fy": ..., "cx": ..., "cy": ...}``
(pixels), or ``{"K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]}``, with
OpenCV's distortion coefficients as ``"dist": [k1, k2, p1, p2, ...]`` where
the lens distorts: a test image is then undistorted before the search, and
``R_cam_obj``, ``t_cam_obj`` are in the undistorted camera's frame (same
intrinsics, no distortion).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from posevote._io import parse_json
from posevote.geometry import rotation_from_pose
from posevote.results import Hypothesis

#: How many distortion coefficients OpenCV takes (none, or one of its models).
DIST_LENGTHS = (0, 4, 5, 8, 12, 14)


@dataclasses.dataclass(frozen=True, kw_only=True)
class Camera:
    """Pinhole intrinsics, pixels (OpenCV's camera frame: +X right, +Y down, +Z forward), and
    the lens's distortion.

    Attributes
    ----------
    fx, fy : float
        Focal lengths, pixels (positive).
    cx, cy : float
        Principal point, pixels.
    dist : tuple of float
        OpenCV's distortion coefficients ``(k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2,
        s3, s4[, tx, ty]]]])``: 4, 5, 8, 12 or 14 numbers; empty for none. A test
        image is undistorted with them (:meth:`undistort`) before the search, so
        that poses are in the undistorted camera's frame, of the same ``fx, fy,
        cx, cy``.

    Examples
    --------
    >>> camera = Camera(fx=500.0, fy=500.0, cx=320.0, cy=240.0)
    >>> camera.project([0.1, 0.0, 2.0]).tolist()
    [345.0, 240.0]
    >>> camera.ray_point(345.0, 240.0, 2.0).tolist()
    [0.1, 0.0, 2.0]
    """

    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        self._check_intrinsics()
        try:
            dist = tuple(float(v) for v in self.dist)
        except (TypeError, ValueError):
            dist = (math.nan,)
        if isinstance(self.dist, (str, bytes)) or len(dist) not in DIST_LENGTHS \
                or not all(math.isfinite(v) and abs(v) <= 1e4 for v in dist):
            raise ValueError(f"Camera.dist must be OpenCV's distortion coefficients: "
                             f"{', '.join(map(str, DIST_LENGTHS[1:]))} finite numbers (or none), "
                             f"got {self.dist!r}")
        object.__setattr__(self, "dist", dist)

    def undistort(self, image: NDArray[np.floating]) -> NDArray[np.float64]:
        """``image`` as the undistorted camera of the same intrinsics sees it (the image
        itself where there are no distortion coefficients)."""
        if not self.dist:
            return np.asarray(image, dtype=np.float64)
        out = cv2.undistort(np.asarray(image, dtype=np.float32), self.K,
                            np.asarray(self.dist, dtype=np.float64))
        return np.asarray(out, dtype=np.float64)

    def _check_intrinsics(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            ok = isinstance(value, (int, float, np.integer, np.floating)) \
                and not isinstance(value, bool) and math.isfinite(float(value)) \
                and abs(float(value)) < 1e7
            # A focal length under a pixel is no camera's (normalised intrinsics, a typo).
            if not ok or (name in ("fx", "fy") and float(value) < 1.0):
                kind = "a positive number (at least 1)" if name in ("fx", "fy") \
                    else "a finite number"
                raise ValueError(f"Camera.{name} must be {kind} of pixels, got {value!r}")
            object.__setattr__(self, name, float(value))

    @property
    def K(self) -> NDArray[np.float64]:
        """The 3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def project(self, point: ArrayLike) -> NDArray[np.float64]:
        """The image ``(u, v)`` of a point of the camera frame (metres, in front of the camera)."""
        x, y, z = np.asarray(point, dtype=np.float64)
        return np.array([self.fx * x / z + self.cx, self.fy * y / z + self.cy])

    def ray_point(self, u: float, v: float, depth: float) -> NDArray[np.float64]:
        """The point at ``depth`` (metres) on the ray through pixel ``(u, v)``, camera frame."""
        return np.array([(u - self.cx) / self.fx * depth, (v - self.cy) / self.fy * depth, depth])

    @classmethod
    def from_dict(cls, data: Any, *, where: str = "camera") -> Camera:
        """A camera from ``{"fx", "fy", "cx", "cy"}`` or ``{"K": 3x3}``.

        Raises
        ------
        ValueError
            On any other shape of data (the message starts with ``where``).
        """
        if not isinstance(data, dict):
            raise ValueError(f"{where}: expected an object with fx, fy, cx, cy or K")
        try:
            for key in ("width", "height"):
                size = data.get(key)
                if key in data and (isinstance(size, bool) or not isinstance(size, int)
                                    or not 0 < size <= 100_000):
                    raise ValueError(f"{key} must be a whole number of pixels from 1 to "
                                     f"100000, got {size!r}")
            dist = data.get("dist", ())
            if "K" in data:
                if set(data) - {"K", "width", "height", "dist"}:
                    raise ValueError(f"give K or fx, fy, cx, cy, not both ({sorted(data)})")
                K = np.asarray(data["K"], dtype=np.float64)
                if K.shape != (3, 3) or not np.allclose(K[2], [0, 0, 1]) \
                        or K[0, 1] != 0 or K[1, 0] != 0:
                    raise ValueError(f"K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got "
                                     f"{data['K']!r}")
                return cls(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], dist=dist)
            unknown = sorted(set(data) - {"fx", "fy", "cx", "cy", "width", "height", "dist"})
            missing = [k for k in ("fx", "fy", "cx", "cy") if k not in data]
            if unknown or missing:
                raise ValueError(f"expected fx, fy, cx, cy (missing {missing}, unknown "
                                 f"{unknown})")
            return cls(fx=data["fx"], fy=data["fy"], cx=data["cx"], cy=data["cy"], dist=dist)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{where}: {exc}") from None

    def to_dict(self) -> dict[str, Any]:
        """``{"fx", "fy", "cx", "cy"}``, and ``"dist"`` where the lens has distortion."""
        out: dict[str, Any] = {k: getattr(self, k) for k in ("fx", "fy", "cx", "cy")}
        if self.dist:
            out["dist"] = list(self.dist)
        return out


def read_camera(path: str | Path) -> Camera:
    """Read a camera file (JSON; the module docstring gives the format).

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If it is not JSON of the camera format (the message names the file).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"camera file not found: {path}")
    if path.stat().st_size > 1 << 20:
        raise ValueError(f"{path}: too large for a camera file")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not a JSON camera file ({exc})") from None
    return Camera.from_dict(parse_json(text, str(path), kind="a JSON camera file"),
                            where=str(path))


def object_height_from_distances(box_heights_px: ArrayLike, distances_m: ArrayLike,
                                 camera: Camera | Sequence[Camera]) -> float:
    """The object's height in metres from training views at known distances.

    Parameters
    ----------
    box_heights_px : array_like, shape (K,)
        Each training view's box height, pixels.
    distances_m : array_like, shape (K,)
        The camera's distance to the object's reference point in each view, metres.
    camera : Camera or sequence of Camera
        The training camera, or each view's.

    Returns
    -------
    float
        The median over the views of ``height * distance / fy``.
    """
    h = np.asarray(box_heights_px, dtype=np.float64)
    d = np.asarray(distances_m, dtype=np.float64)
    if h.shape != d.shape or h.ndim != 1 or len(h) == 0:
        raise ValueError(f"distances_m: one distance per training view needed ({len(h)} "
                         f"views, {d.size} distances)")
    if not (np.all(np.isfinite(d)) and np.all(d > 0)):
        raise ValueError("distances_m must be positive, finite numbers of metres")
    fy = _focal_y(camera, len(h))
    if fy.shape != h.shape:
        raise ValueError(f"camera: one camera per training view needed ({len(h)} views, "
                         f"{len(fy)} cameras)")
    return float(np.median(h * d / fy))


def _focal_y(camera: Camera | Sequence[Camera], n: int) -> NDArray[np.float64]:
    """``fy`` of each of ``n`` views: one camera's for all, or each view's camera's."""
    return (np.full(n, camera.fy) if isinstance(camera, Camera)
            else np.array([c.fy for c in camera], dtype=np.float64))


def origin_depth_factors(depths_m: ArrayLike, camera: Camera | Sequence[Camera], *,
                         object_height_m: float, reference_size_px: float
                         ) -> NDArray[np.float64]:
    """Each training origin's depth over the depth a model gives its view at training size.

    The third column of ``fit(..., origins=)``: a model places a view seen at
    scale 1 at depth ``fy * object_height_m / reference_size_px``; an origin
    off the object's centre along the line of sight lies nearer or farther
    by this factor.

    Parameters
    ----------
    depths_m : array_like, shape (K,)
        Each training view's origin depth (its z in the camera frame), metres.
    camera : Camera or sequence of Camera
        The training camera, or each view's.
    object_height_m : float
        The object's height (:func:`object_height_from_distances`).
    reference_size_px : float
        The model's reference box height: the median training box height for
        one instance.

    Returns
    -------
    ndarray, shape (K,)
    """
    d = np.asarray(depths_m, dtype=np.float64).reshape(-1)
    return d * float(reference_size_px) / (_focal_y(camera, len(d)) * float(object_height_m))


def check_object_height(value: Any) -> float | None:
    """``object_height_m`` as a float, or None; refused unless positive and finite (metres)."""
    if value is None:
        return None
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not (ok and math.isfinite(float(value)) and 0 < float(value) < 1e4):
        raise ValueError(f"object_height_m must be a positive number of metres, got {value!r}")
    return float(value)


def scale_range_for_depths(depths_m: ArrayLike, camera: Camera, *, object_height_m: float | None,
                           reference_size_px: float) -> tuple[float, float]:
    """The search's scale range (``SearchOptions.scale_range``) of a range of depths.

    A robot that knows its working distances need not search the scales it
    cannot see: the depth of the reference point is ``fy * H / (scale * R)``
    (the module docstring), so the nearest depth gives the largest scale.

    Parameters
    ----------
    depths_m : array_like, shape (2,)
        The nearest and the farthest depth of the object's reference point, metres.
    camera : Camera
        The test camera.
    object_height_m : float or None
        The model's object height (``PoseEstimator.object_height_m_``).
    reference_size_px : float
        The model's reference box height, pixels.

    Returns
    -------
    (float, float)
        The smallest and the largest scale.

    Raises
    ------
    ValueError
        If the depths are not two positive, finite metres, nearest first, or
        the model has no object height (it was trained without distances).
    """
    try:
        near, far = (float(d) for d in np.asarray(depths_m, dtype=np.float64).reshape(2))
    except (TypeError, ValueError):
        raise ValueError(f"depth range must be two numbers of metres, got {depths_m!r}") from None
    if not (math.isfinite(near) and math.isfinite(far) and 0 < near < far < 1e4):
        raise ValueError(f"depth range must be 0 < nearest < farthest metres, got {depths_m!r}")
    if object_height_m is None:
        raise ValueError("a depth range needs the object's height: train with a distance_m "
                         "column and a camera, or give object_height_m")
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a posevote.camera.Camera, got {type(camera).__name__}")
    unit = camera.fy * object_height_m / reference_size_px
    return unit / far, unit / near


def place(hypothesis: Hypothesis, camera: Camera, *, reference_size_px: float,
          object_height_m: float | None, anchor: tuple[float, float] | None = None,
          depth_factor: float = 1.0) -> Hypothesis:
    """The hypothesis with ``R_cam_obj`` and, given the object's height, ``t_cam_obj``.

    ``t_cam_obj`` is the ray through ``anchor`` (the image of the object's
    origin, when the model knows it; default: the box centre, ``position``)
    at the object's depth times ``depth_factor`` (the origin's, when the
    model knows it).
    """
    R = rotation_from_pose(hypothesis.azimuth, hypothesis.elevation, hypothesis.inplane)
    t: tuple[float, float, float] | None = None
    if object_height_m is not None:
        depth = depth_factor * camera.fy * object_height_m / (hypothesis.scale
                                                              * reference_size_px)
        u, v = hypothesis.position if anchor is None else anchor
        x, y, z = camera.ray_point(float(u), float(v), depth).tolist()
        t = (x, y, z)
    return dataclasses.replace(hypothesis, R_cam_obj=_rows(R), t_cam_obj=t)


def place_all(hypotheses: Sequence[Hypothesis], camera: Camera | None, *,
              reference_size_px: float, object_height_m: float | None,
              anchors: Sequence[tuple[float, float, float] | None] | None = None
              ) -> list[Hypothesis]:
    """:func:`place` for every hypothesis, each with its anchor, ``(u, v, depth_factor)``
    (unchanged without a camera)."""
    if camera is None:
        return list(hypotheses)
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a posevote.camera.Camera, got {type(camera).__name__}")
    points = [None] * len(hypotheses) if anchors is None else list(anchors)
    return [place(h, camera, reference_size_px=reference_size_px,
                  object_height_m=object_height_m,
                  anchor=None if a is None else (a[0], a[1]),
                  depth_factor=1.0 if a is None else a[2])
            for h, a in zip(hypotheses, points, strict=True)]


def _rows(R: NDArray[np.float64]) -> tuple[tuple[float, float, float], ...]:
    return tuple((float(r[0]), float(r[1]), float(r[2])) for r in R)
