"""The embedded default: a whole train-and-estimate run that needs no download.

A textured mesh that ships inside the ``pybullet`` wheel (``pybullet_data``'s
rubber duck) is rendered on a turntable with pybullet's CPU renderer: 18
training views, one every 20 degrees, with their segmentation masks. Test
views at other azimuths are pasted at random position, scale (0.7-1.3) and
in-plane rotation (+-30 degrees) onto cluttered crops of scikit-image's
bundled photographs, with 20% of the duck hidden. posevote trains on the
clean views, estimates every test image and reports the errors.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from posevote.estimator import PoseEstimator
from posevote.evaluation.metrics import summarize_errors
from posevote.evaluation.plots import draw_overlay, write_png
from posevote.evaluation.synthetic import paste_on_clutter
from posevote.geometry import angular_error

#: Vertical field of view of the renderer, degrees.
RENDER_FOV_DEG = 40.0


@dataclass(frozen=True, kw_only=True, eq=False)
class RenderedView:
    """A rendered view: grey image, object mask, object box, azimuth (radians), camera distance (m)."""

    image: NDArray[np.float64]
    mask: NDArray[np.bool_]
    box: NDArray[np.float64]
    azimuth: float
    distance: float = float("nan")


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
        raise ImportError("the demo renders with pybullet: pip install 'posevote[demo]'") from exc
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
            out.append(RenderedView(image=gray, mask=mask, box=box, azimuth=float(az),
                                    distance=float(distance)))
        return out
    finally:
        pybullet.disconnect(client)


#: The demo's preset: the cluttered search with the local refinement. Its
#: values were chosen on the cluttered COIL benchmark and checked on seeds 1-3
#: of the demo's own generator, never on seed 0, which the demo reports
#: (``benchmarks/tune_demo.py``, docs/DEFAULTS.md).
DEMO_PRESET = "cluttered"


def run_demo(out_dir: str | Path, *, n_test: int = 24, seed: int = 0,
             log: Callable[[str], None] = lambda s: None,
             overrides: dict[str, Any] | None = None) -> dict:
    """Train on rendered views, estimate cluttered test images, write overlays.

    Parameters
    ----------
    out_dir : str or Path
        Folder for the overlays and ``results.csv``.
    n_test : int, optional
        Number of test images.
    seed : int, optional
        Seed of the test azimuths, placements and backgrounds.
    log : callable, optional
        Receives progress lines (the CLI prints them).
    overrides : dict, optional
        :meth:`~posevote.estimator.PoseEstimator.set_params` overrides of the
        :data:`DEMO_PRESET` preset.

    Returns
    -------
    dict
        Error summary (degrees) and position accuracy.
    """
    from posevote._io import atomic_write_text

    rng = np.random.default_rng(seed)
    out_dir = Path(out_dir)
    train = render_turntable(np.radians(np.arange(0, 360, 20)))
    log(f"rendered {len(train)} training views of pybullet's duck (one every 20 degrees)")
    estimator = PoseEstimator.from_preset(DEMO_PRESET, **(overrides or {}))
    estimator.fit([v.image for v in train], [v.azimuth for v in train],
                  boxes=[v.box for v in train], masks=[v.mask for v in train])
    log(f"trained: {estimator.model_.n_features} features")
    test_az = np.radians(rng.uniform(0.0, 360.0, n_test))
    test = render_turntable(test_az)
    rows = ["image,azimuth_true_deg,azimuth_est_deg,error_deg,position_error_px,score,seconds"]
    errors, pos_errors = [], []
    for i, view in enumerate(test):
        pasted = paste_on_clutter(view.image, view.box, rng=rng, mask=view.mask)
        est = estimator.estimate(pasted.image)
        if est.best is None:
            err, pos_err, az_est, score = 180.0, float("inf"), float("nan"), 0.0
        else:
            err = float(np.degrees(angular_error(est.best.azimuth, view.azimuth)))
            pos_err = float(np.hypot(*(np.array(est.best.position) - pasted.position)))
            az_est, score = est.best.azimuth_deg, est.best.score
        errors.append(err)
        pos_errors.append(pos_err)
        name = f"test_{i:02d}.png"
        overlay = draw_overlay(pasted.image, est, truth_box=pasted.box,
                               label=f"true {np.degrees(view.azimuth):.0f} est {az_est:.0f} deg")
        write_png(out_dir / name, overlay)
        rows.append(f"{name},{np.degrees(view.azimuth):.2f},{az_est:.2f},{err:.2f},{pos_err:.2f},"
                    f"{score:.4f},{est.seconds:.4f}")
        log(f"{name}: true {np.degrees(view.azimuth):6.1f}  estimated {az_est:6.1f}  "
            f"error {err:5.1f} deg  position error {pos_err:5.1f} px  ({1000 * est.seconds:.0f} ms)")
    atomic_write_text(out_dir / "results.csv", "\n".join(rows) + "\n")
    summary = summarize_errors(errors)
    summary["position_within_5px"] = float(100.0 * np.mean(np.array(pos_errors) <= 5.0))
    return summary
