"""Rendered views of the textured meshes that ship inside the ``pybullet`` wheel.

pybullet's CPU renderer draws a mesh of ``pybullet_data`` on a turntable, at
any camera elevation, framed or at a given distance, with its segmentation
mask and box: the embedded data of the demo and of the rendered-sphere
protocol (nothing to download).
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

#: Meshes of pybullet_data and the rest orientation (roll, pitch, yaw) that
#: stands each upright on the turntable.
MESHES: dict[str, tuple[float, float, float]] = {
    "r2d2.urdf": (0.0, 0.0, 0.0), "duck_vhacd.urdf": (np.pi / 2, 0.0, 0.0),
    "teddy_vhacd.urdf": (np.pi / 2, 0.0, 0.0), "jenga/jenga.urdf": (0.0, 0.0, 0.0)}

#: Vertical field of view of the renderer, degrees.
RENDER_FOV_DEG = 40.0


@dataclass(frozen=True, kw_only=True, eq=False)
class RenderedView:
    """A rendered view: grey image, object mask, object box, azimuth (radians), camera distance
    (m), and the mesh's origin in the camera frame (m, OpenCV axes: x right, y down, z ahead)."""

    image: NDArray[np.float64]
    mask: NDArray[np.bool_]
    box: NDArray[np.float64]
    azimuth: float
    distance: float = float("nan")
    origin: NDArray[np.float64] = field(default_factory=lambda: np.full(3, np.nan))


def camera_point(view_matrix: Sequence[float], point: NDArray[np.float64]) -> NDArray[np.float64]:
    """A world point in the camera frame of pybullet's view matrix (OpenGL's, column-major:
    y up, looking down -z), turned to OpenCV's axes (y down, z ahead), metres."""
    gl = np.reshape(np.asarray(view_matrix, dtype=np.float64), (4, 4)).T @ np.append(point, 1.0)
    return np.array([gl[0], -gl[1], -gl[2]])


def render_focal(size: int) -> float:
    """The renderer's focal length, pixels, for a square image of ``size`` pixels."""
    return (size / 2.0) / float(np.tan(np.radians(RENDER_FOV_DEG / 2.0)))


def render_turntable(azimuths: NDArray[np.float64], *, size: int = 128, elevation_deg: float = 20.0,
                     distance: float | None = 0.24, mesh: str = "duck_vhacd.urdf",
                     base_euler: tuple[float, float, float] = (np.pi / 2, 0.0, 0.0),
                     target: tuple[float, float, float] = (0.0, 0.0, 0.02),
                     texture: str | None = None) -> list[RenderedView]:
    """Render a mesh of ``pybullet_data`` on a turntable at the given azimuths (radians).

    Parameters
    ----------
    azimuths : ndarray
        Turntable angles, radians.
    size : int, optional
        Side of the square image, pixels.
    elevation_deg : float, optional
        Camera elevation above the turntable, degrees.
    distance : float or None, optional
        Camera distance, metres. None frames the object: the camera looks at
        the centre of its bounding box from where the box's circumscribed
        sphere just fits in the field of view, and the object turns about
        the vertical through that centre (``target`` is then ignored).
    mesh : str, optional
        URDF file, relative to ``pybullet_data`` (the default is the demo's
        rubber duck).
    base_euler : tuple of float, optional
        Rest orientation of the mesh (roll, pitch, yaw; radians) before the
        turntable's rotation; the duck's mesh lies on its side without it.
    target : tuple of float, optional
        Point the camera looks at when ``distance`` is given, metres.
    texture : str, optional
        An image file, relative to ``pybullet_data``, laid over every link by the mesh's own
        texture coordinates (its material's colour replaced by white); None keeps the
        material.

    Raises
    ------
    ImportError
        If pybullet is not installed (``pip install 'posevote[demo]'``).
    FileNotFoundError
        If ``texture`` is not a file of ``pybullet_data``.
    """
    try:
        import pybullet
        import pybullet_data
    except ImportError as exc:  # pragma: no cover - exercised without the extra
        raise ImportError("rendering needs pybullet: pip install 'posevote[demo]'") from exc
    client = pybullet.connect(pybullet.DIRECT)
    try:
        pybullet.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=client)
        body = pybullet.loadURDF(mesh, useFixedBase=True, physicsClientId=client)
        if texture is not None:
            _lay_texture(pybullet, client, body, texture)
        rest = pybullet.getQuaternionFromEuler(list(base_euler))
        pivot = np.zeros(3)
        if distance is None:
            pybullet.resetBasePositionAndOrientation(body, [0.0, 0.0, 0.0], rest,
                                                     physicsClientId=client)
            bounds = [pybullet.getAABB(body, link, physicsClientId=client)
                      for link in range(-1, pybullet.getNumJoints(body, physicsClientId=client))]
            lo = np.min([b[0] for b in bounds], axis=0)
            hi = np.max([b[1] for b in bounds], axis=0)
            target = tuple((lo + hi) / 2.0)
            distance = float(np.linalg.norm(hi - lo)) / 2.0 / np.sin(np.radians(RENDER_FOV_DEG / 2))
            pivot = np.array([target[0], target[1], 0.0])
        proj = pybullet.computeProjectionMatrixFOV(fov=RENDER_FOV_DEG, aspect=1.0, nearVal=0.01,
                                                   farVal=10.0 * distance + 10.0)
        view = pybullet.computeViewMatrixFromYawPitchRoll(
            cameraTargetPosition=list(target), distance=distance, yaw=0.0,
            pitch=-elevation_deg, roll=0.0, upAxisIndex=2)
        out = []
        for az in azimuths:
            turn = pybullet.getQuaternionFromEuler([0.0, 0.0, float(az)])
            _, orientation = pybullet.multiplyTransforms([0.0, 0.0, 0.0], turn,
                                                         [0.0, 0.0, 0.0], rest)
            turn_matrix = np.reshape(pybullet.getMatrixFromQuaternion(turn), (3, 3))
            pybullet.resetBasePositionAndOrientation(body, list(pivot - turn_matrix @ pivot),
                                                     orientation, physicsClientId=client)
            _, _, rgba, _, seg = pybullet.getCameraImage(
                size, size, view, proj, renderer=pybullet.ER_TINY_RENDERER, physicsClientId=client)
            rgb = np.reshape(np.asarray(rgba, dtype=np.uint8), (size, size, 4))[..., :3]
            # the body id is in the low 24 bits (pybullet puts a link index above them
            # when asked to; masking is harmless otherwise)
            mask = (np.reshape(np.asarray(seg), (size, size)) & 0xFFFFFF) == body
            if not mask.any():
                raise ValueError(f"{mesh}: the object is not in view at azimuth "
                                 f"{np.degrees(az):.1f} degrees")
            gray = (rgb.astype(np.float64) / 255.0) @ np.array([0.299, 0.587, 0.114])
            gray = np.where(mask, gray, 0.0)  # object on black, as COIL-100
            rows, cols = np.nonzero(mask)
            box = np.array([cols.min(), rows.min(), np.ptp(cols) + 1, np.ptp(rows) + 1], dtype=float)
            position, _ = pybullet.getBasePositionAndOrientation(body, physicsClientId=client)
            out.append(RenderedView(image=gray, mask=mask, box=box, azimuth=float(az),
                                    distance=float(distance),
                                    origin=camera_point(view, np.asarray(position))))
        return out
    finally:
        pybullet.disconnect(client)


def texture_path(texture: str) -> str:
    """The file of ``texture``, an image relative to ``pybullet_data``.

    Raises
    ------
    FileNotFoundError
        If there is no such file.
    """
    import pybullet_data

    path = os.path.join(pybullet_data.getDataPath(), texture)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"texture {texture!r}: no such image in pybullet_data "
                                f"({pybullet_data.getDataPath()})")
    return path


def _lay_texture(pybullet: Any, client: int, body: int, texture: str) -> None:
    """Lay the image ``texture`` of ``pybullet_data`` over every link of ``body``."""
    image = pybullet.loadTexture(texture_path(texture), physicsClientId=client)
    for link in range(-1, pybullet.getNumJoints(body, physicsClientId=client)):
        pybullet.changeVisualShape(body, link, textureUniqueId=image,
                                   rgbaColor=[1.0, 1.0, 1.0, 1.0], physicsClientId=client)


def gl_projection(fx: float, fy: float, cx: float, cy: float, size: tuple[int, int], *,
                  near: float = 0.01, far: float = 20.0) -> list[float]:
    """pybullet's (OpenGL's, column-major) projection matrix of a pinhole camera: focal
    lengths and principal point in pixels, ``size`` the image's ``(width, height)``."""
    w, h = size
    # pybullet's tiny renderer draws a row higher than the pinhole puts it: one down.
    cy = cy + 1.0
    P = np.array([[2 * fx / w, 0.0, 1.0 - 2 * cx / w, 0.0],
                  [0.0, 2 * fy / h, 2 * cy / h - 1.0, 0.0],
                  [0.0, 0.0, -(far + near) / (far - near), -2 * far * near / (far - near)],
                  [0.0, 0.0, -1.0, 0.0]])
    return [float(v) for v in P.T.ravel()]


def gl_view(R_cam_world: NDArray[np.float64], t_cam_world: NDArray[np.float64]) -> list[float]:
    """pybullet's view matrix of an OpenCV camera pose (x right, y down, z ahead)."""
    M = np.eye(4)
    M[:3, :3] = R_cam_world
    M[:3, 3] = t_cam_world
    return [float(v) for v in (np.diag([1.0, -1.0, -1.0, 1.0]) @ M).T.ravel()]


def render_posed(poses: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]], *,
                 intrinsics: tuple[float, float, float, float], size: tuple[int, int],
                 mesh: str = "duck_vhacd.urdf",
                 base_euler: tuple[float, float, float] = (np.pi / 2, 0.0, 0.0)
                 ) -> list[tuple[NDArray[np.uint8], NDArray[np.bool_]]]:
    """Render a mesh of ``pybullet_data`` standing on the plane ``z = 0`` from given camera
    poses: its colour image (RGB, uint8) and its mask per pose.

    The mesh stands in its rest orientation with its bounding box's bottom centre at the
    world's origin, ``+z`` up: the object frame of a footprint
    (:class:`posevote.capture.Footprint`) centred under it.

    Parameters
    ----------
    poses : sequence of (ndarray, ndarray)
        ``R_cam_world`` (3x3) and ``t_cam_world`` (metres), OpenCV's camera axes.
    intrinsics : (fx, fy, cx, cy)
        The pinhole camera, pixels (no distortion).
    size : (int, int)
        The image's width and height.
    mesh, base_euler
        As :func:`render_turntable`.
    """
    fx, fy, cx, cy = intrinsics
    with _standing(mesh, base_euler) as (pybullet, client, body, _):
        proj = gl_projection(fx, fy, cx, cy, size)
        out = []
        for R, t in poses:
            _, _, rgba, _, seg = pybullet.getCameraImage(
                size[0], size[1], gl_view(R, t), proj, renderer=pybullet.ER_TINY_RENDERER,
                physicsClientId=client)
            rgb = np.reshape(np.asarray(rgba, dtype=np.uint8), (size[1], size[0], 4))[..., :3]
            mask = (np.reshape(np.asarray(seg), (size[1], size[0])) & 0xFFFFFF) == body
            out.append((np.ascontiguousarray(rgb), mask))
        return out


def mesh_size(mesh: str = "duck_vhacd.urdf",
              base_euler: tuple[float, float, float] = (np.pi / 2, 0.0, 0.0)
              ) -> NDArray[np.float64]:
    """The extent (x, y, z; metres) of a mesh of ``pybullet_data`` in its rest orientation."""
    with _standing(mesh, base_euler) as (_, _, _, extent):
        return extent


@contextmanager
def _standing(mesh: str, base_euler: tuple[float, float, float]
              ) -> Iterator[tuple[Any, int, int, NDArray[np.float64]]]:
    """pybullet, a client, the mesh in its rest orientation standing on ``z = 0`` (its visual
    bounding box's bottom centre at the origin) and that box's extent; disconnected after."""
    import pybullet
    import pybullet_data

    client = pybullet.connect(pybullet.DIRECT)
    try:
        pybullet.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=client)
        rest = pybullet.getQuaternionFromEuler(list(base_euler))
        body = pybullet.loadURDF(mesh, useFixedBase=True, baseOrientation=rest,
                                 physicsClientId=client)
        lo, hi = _visual_bounds(pybullet, body, client)
        base = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
        position, _ = pybullet.getBasePositionAndOrientation(body, physicsClientId=client)
        pybullet.resetBasePositionAndOrientation(body, list(np.asarray(position) - base), rest,
                                                 physicsClientId=client)
        yield pybullet, client, body, np.asarray(hi - lo, dtype=np.float64)
    finally:
        pybullet.disconnect(client)


def _visual_bounds(pybullet: Any, body: int, client: int
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The world bounds of a one-link body's visual meshes (``.obj``): its collision
    hull's (``getAABB``) can be larger or offset."""
    position, orientation = pybullet.getBasePositionAndOrientation(body, physicsClientId=client)
    inertial_pos, inertial_orn = pybullet.getDynamicsInfo(body, -1, physicsClientId=client)[3:5]
    # pybullet's base pose is its centre of mass: the link frame is that less the inertial offset.
    inv_pos, inv_orn = pybullet.invertTransform(inertial_pos, inertial_orn)
    link_pos, link_orn = pybullet.multiplyTransforms(position, orientation, inv_pos, inv_orn)
    points = []
    for shape in pybullet.getVisualShapeData(body, physicsClientId=client):
        scale, filename, local_pos, local_orn = shape[3], shape[4], shape[5], shape[6]
        with open(filename, encoding="utf-8", errors="replace") as handle:
            vertices = np.array([[float(x) for x in line.split()[1:4]] for line in handle
                                 if line.startswith("v ")])
        pos, orn = pybullet.multiplyTransforms(link_pos, link_orn, local_pos, local_orn)
        R = np.reshape(pybullet.getMatrixFromQuaternion(orn), (3, 3))
        points.append((vertices * np.asarray(scale)) @ R.T + np.asarray(pos))
    if not points:
        lo, hi = pybullet.getAABB(body, physicsClientId=client)
        return np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    stacked = np.vstack(points)
    return stacked.min(axis=0), stacked.max(axis=0)
