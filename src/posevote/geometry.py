"""Angles, rotations and the conventions every other module relies on.

Conventions, stated once for the whole library:

* Angles are in **radians** everywhere inside the library; degrees appear only
  at the edges (CLI flags, files, reports) and then the name says so
  (``azimuth_deg``).
* Images are indexed ``(row, col)``; pixel coordinates are ``(u, v)`` with
  ``u`` the column and ``v`` the row, origin at the top-left pixel centre.
* Image orientations (edge tangents, in-plane rotations) are measured in the
  ``(u, v)`` plane from the ``+u`` axis towards the ``+v`` axis, i.e. positive
  is **clockwise on screen** because ``v`` points down. An in-plane rotation
  by ``alpha`` maps ``(u, v)`` to ``R(alpha) @ (u, v)`` with
  ``R = [[cos, -sin], [sin, cos]]`` and adds ``alpha`` to orientations.
* The camera frame is OpenCV's: ``+X`` right, ``+Y`` down, ``+Z`` forward.
* The object frame has ``+z`` up (the turntable axis) and ``+x`` pointing at
  the camera when azimuth, elevation and in-plane angle are all zero.
  Azimuth turns the object about its ``+z`` axis (as a turntable does),
  elevation raises the camera above the object's equator, and the in-plane
  angle turns the image about the optical axis.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

TWO_PI = 2.0 * np.pi
#: A pose is right when the true viewpoint is within this angle of it: a mode's radius
#: (:mod:`posevote.refinement.probability`), and how far apart two sides of an object lie
#: (:mod:`posevote.refinement.lookalike`).
MODE_RADIUS = np.radians(30.0)

# Fixed rotation taking object axes to camera axes at zero pose: object +x
# (front) points to the camera (-Z), object +z (up) is image up (-Y).
_R_CAM_OBJ_ZERO = np.array(
    [
        [0.0, 1.0, 0.0],
        [0.0, 0.0, -1.0],
        [-1.0, 0.0, 0.0],
    ]
)


def wrap_angle(angle: ArrayLike, *, period: float = TWO_PI) -> NDArray[np.float64]:
    """Wrap angles into ``[0, period)``.

    Parameters
    ----------
    angle : array_like
        Angles in radians.
    period : float, optional
        Period of the circle, ``2*pi`` by default (``pi`` for undirected
        orientations or objects with a half-turn symmetry).

    Returns
    -------
    ndarray
        Wrapped angles, same shape as ``angle``.
    """
    out = np.mod(np.asarray(angle, dtype=np.float64), period)
    # np.mod can return `period` itself for tiny negative inputs.
    return np.where(out >= period, 0.0, out)


def angle_difference(a: ArrayLike, b: ArrayLike, *, period: float = TWO_PI) -> NDArray[np.float64]:
    """Signed difference ``a - b`` wrapped into ``[-period/2, period/2)``."""
    half = period / 2.0
    return wrap_angle(np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64) + half,
                      period=period) - half


def angular_error(estimate: ArrayLike, truth: ArrayLike, *, period: float = TWO_PI
                  ) -> NDArray[np.float64]:
    """Absolute angular error on a circle, in ``[0, period/2]``.

    Parameters
    ----------
    estimate, truth : array_like
        Angles in radians (broadcastable).
    period : float, optional
        ``2*pi`` for a full circle; ``pi`` for objects that look alike after a
        half turn, whose error is the minimum over their two symmetric poses.

    Returns
    -------
    ndarray
        Absolute errors in radians; symmetric in its arguments and zero on
        identical angles.
    """
    return np.abs(angle_difference(estimate, truth, period=period))


def viewing_direction(azimuth: ArrayLike, elevation: ArrayLike) -> NDArray[np.float64]:
    """Unit vector, in the object frame, from the object towards the camera.

    Parameters
    ----------
    azimuth, elevation : array_like
        Viewpoint angles in radians (broadcastable).

    Returns
    -------
    ndarray, shape (..., 3)
    """
    az = np.asarray(azimuth, dtype=np.float64)
    el = np.asarray(elevation, dtype=np.float64)
    # Turning the object by +az about z makes the camera see the object from
    # the object's own direction -az.
    return np.stack(
        np.broadcast_arrays(np.cos(el) * np.cos(-az), np.cos(el) * np.sin(-az), np.sin(el)),
        axis=-1,
    )


def rotation_from_pose(azimuth: float, elevation: float, inplane: float) -> NDArray[np.float64]:
    """Rotation ``R_cam_obj`` (3x3) of a viewpoint and in-plane angle.

    ``R_cam_obj = Rz_cam(inplane) @ Rx_cam(elevation) @ R0 @ Rz_obj(azimuth)``
    with ``R0`` the zero pose described in the module docstring.

    Parameters
    ----------
    azimuth, elevation, inplane : float
        Pose angles in radians.

    Returns
    -------
    ndarray, shape (3, 3)
        Orthonormal rotation with determinant +1.
    """
    # imported where used, so that a command-line start does not pay for it
    from scipy.spatial.transform import Rotation

    r_turn = Rotation.from_euler("z", azimuth).as_matrix()
    # Raising the camera by `elevation` tilts the scene about the camera's X
    # axis so that the object's top turns towards the camera.
    r_elev = Rotation.from_euler("x", elevation).as_matrix()
    r_roll = Rotation.from_euler("z", inplane).as_matrix()
    return r_roll @ r_elev @ _R_CAM_OBJ_ZERO @ r_turn


def pose_from_rotation(R_cam_obj: ArrayLike) -> tuple[float, float, float]:
    """Inverse of :func:`rotation_from_pose`.

    Parameters
    ----------
    R_cam_obj : array_like, shape (3, 3)
        Rotation matrix.

    Returns
    -------
    azimuth, elevation, inplane : float
        Azimuth and in-plane angle in ``[0, 2*pi)``, elevation in
        ``[-pi/2, pi/2]`` (radians).
    """
    R = np.asarray(R_cam_obj, dtype=np.float64)
    if R.shape != (3, 3):
        raise ValueError(f"R_cam_obj must have shape (3, 3), got {R.shape}")
    M = R @ _R_CAM_OBJ_ZERO.T  # = Rz(inplane) Rx(el) R0 Rz(az) R0^T
    # R0 Rz(az) R0^T is a rotation about R0 @ z = -Y (camera), i.e. about Y.
    # So M = Rz(c) Rx(b) Ry(a') : intrinsic z-x-y Euler angles.
    from scipy.spatial.transform import Rotation

    c, b, a = Rotation.from_matrix(M).as_euler("ZXY")
    return float(wrap_angle(-a)), float(b), float(wrap_angle(c))


def transform_from_pose(azimuth: float, elevation: float, inplane: float, scale: float,
                        u: float, v: float, *, K: ArrayLike, reference_depth: float
                        ) -> NDArray[np.float64]:
    """Full rigid transform ``T_cam_obj`` (4x4) from an image-space pose.

    The depth is ``reference_depth / scale`` (scale stands for depth, METHOD.md
    "Pose, split in three") and the object's reference point back-projects
    through pixel ``(u, v)`` with intrinsics ``K``.

    Parameters
    ----------
    azimuth, elevation, inplane : float
        Pose angles in radians.
    scale : float
        Apparent size relative to the training images (> 0).
    u, v : float
        Image position of the object's reference point, in pixels.
    K : array_like, shape (3, 3)
        Camera intrinsics.
    reference_depth : float
        Distance from the camera at which the object appears at scale 1.

    Returns
    -------
    ndarray, shape (4, 4)
    """
    if not scale > 0:
        raise ValueError(f"scale must be positive, got {scale}")
    K = np.asarray(K, dtype=np.float64)
    depth = reference_depth / scale
    ray = np.linalg.solve(K, np.array([u, v, 1.0]))
    T = np.eye(4)
    T[:3, :3] = rotation_from_pose(azimuth, elevation, inplane)
    T[:3, 3] = ray * depth / ray[2]
    return T


def rotate_points(points: ArrayLike, angle: float) -> NDArray[np.float64]:
    """Rotate ``(u, v)`` points by ``angle`` about the origin (image convention)."""
    c, s = np.cos(angle), np.sin(angle)
    p = np.asarray(points, dtype=np.float64)
    return np.stack([c * p[..., 0] - s * p[..., 1], s * p[..., 0] + c * p[..., 1]], axis=-1)


def rotation_angle(a: ArrayLike, b: ArrayLike) -> float:
    """The angle of the rotation that takes rotation matrix ``b`` to ``a`` (geodesic), radians."""
    r = np.asarray(a, dtype=np.float64) @ np.asarray(b, dtype=np.float64).T
    return float(np.arccos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0)))


def box_centre(box: ArrayLike) -> tuple[float, float]:
    """Centre ``(u, v)`` of the pixels of an ``(x, y, w, h)`` box (pixel centres at integers)."""
    x, y, w, h = (float(b) for b in np.asarray(box, dtype=np.float64))
    return x + (w - 1) / 2.0, y + (h - 1) / 2.0


def box_iou(box_a: ArrayLike, box_b: ArrayLike) -> NDArray[np.float64] | np.float64:
    """Intersection over union of ``(x, y, w, h)`` boxes (broadcastable)."""
    if isinstance(box_a, tuple) and isinstance(box_b, tuple) and len(box_a) == len(box_b) == 4:
        # One pair, as loops ask: the same arithmetic on plain floats, without
        # the arrays' overhead (a training image draws five of them).
        ax, ay, aw, ah = (float(v) for v in box_a)
        bx, by, bw, bh = (float(v) for v in box_b)
        if all(math.isfinite(v) for v in (ax, ay, aw, ah, bx, by, bw, bh)):
            inter = max(min(ax + aw, bx + bw) - max(ax, bx), 0.0) \
                * max(min(ay + ah, by + bh) - max(ay, by), 0.0)
            union = aw * ah + bw * bh - inter
            return np.float64(inter / union if union > 0 else 0.0)
    a = np.asarray(box_a, dtype=np.float64)
    b = np.asarray(box_b, dtype=np.float64)
    x0 = np.maximum(a[..., 0], b[..., 0])
    y0 = np.maximum(a[..., 1], b[..., 1])
    x1 = np.minimum(a[..., 0] + a[..., 2], b[..., 0] + b[..., 2])
    y1 = np.minimum(a[..., 1] + a[..., 3], b[..., 1] + b[..., 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    union = a[..., 2] * a[..., 3] + b[..., 2] * b[..., 3] - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)
