"""Rendered views of the textured meshes that ship inside the ``pybullet`` wheel.

pybullet's CPU renderer draws a mesh of ``pybullet_data`` on a turntable, at
any camera elevation, framed or at a given distance, with its segmentation
mask and box: the embedded data of the demo and of the rendered-sphere
protocol (nothing to download).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

#: Meshes of pybullet_data and the rest orientation (roll, pitch, yaw) that
#: stands each upright on the turntable.
MESHES: dict[str, tuple[float, float, float]] = {
    "r2d2.urdf": (0.0, 0.0, 0.0), "duck_vhacd.urdf": (np.pi / 2, 0.0, 0.0),
    "teddy_vhacd.urdf": (np.pi / 2, 0.0, 0.0)}

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
                     target: tuple[float, float, float] = (0.0, 0.0, 0.02)) -> list[RenderedView]:
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

    Raises
    ------
    ImportError
        If pybullet is not installed (``pip install 'posevote[demo]'``).
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
