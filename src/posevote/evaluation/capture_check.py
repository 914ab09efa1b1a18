"""The rendered capture check: from photographs of an object on the printed board to poses.

pybullet renders a textured mesh of ``pybullet_data`` (the rubber duck) standing
on the generated ChArUco board, photographed from around it as a hand would
(azimuths all round, elevations, tilts and distances varied, the object not
always centred) through a lens with known intrinsics and radial distortion, on
a cluttered table. :func:`posevote.capture.capture` makes the training folder
from these photographs alone (the camera calibrated from them); the truth is
what was rendered. Compared: the calibration (intrinsics, distortion, its
RMS), each photograph's rotation and distance, the boxes and masks (IoU with
the rendered object's). Then a model trained on the captured folder and one
trained on the same photographs with the true poses, boxes and masks estimate
other renders of the object off the board, on clutter, through the same lens
(each with its own camera: the captured ``camera.json``, the true one); their
rotation errors are compared. Everything is rendered: nothing to download.
"""

from __future__ import annotations

import contextlib
import io
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from posevote._io import atomic_write_text
from posevote.camera import Camera
from posevote.capture import R_BOARD_OBJ, BoardSpec, Footprint, capture, squares_image
from posevote.geometry import box_iou, rotation_angle, rotation_from_pose

#: The photographs' size and the lens they are taken through (a phone-like 640 x 480 with
#: barrel distortion).
SIZE = (640, 480)
LENS = Camera(fx=610.0, fy=605.0, cx=322.0, cy=236.0, dist=(-0.12, 0.05, 0.0, 0.0))
#: The board (the default printed one) and where the object stands on it (its centre).
BOARD = BoardSpec()
#: Ranges the photographs and the tests are drawn in: elevation and in-plane angle
#: (degrees; the camera turned further for the photographs, as a hand does between portrait
#: and landscape: a calibration needs the board seen at varied angles), camera distance to
#: the object (metres), the object's shift off the optical axis.
ELEVATION_DEG = (25.0, 60.0)
PHOTO_INPLANE_DEG = (-60.0, 60.0)
INPLANE_DEG = (-25.0, 25.0)
DISTANCE_M = (0.42, 0.6)
OFF_AXIS_M = 0.09
#: A user's rough bounding cylinder: this much larger than the mesh.
ROUGH = 1.1
#: The preset both models are trained with.
PRESET = "cluttered"
#: Board print levels: the black and white of a print under room light.
INK, PAPER = 25.0, 225.0


@dataclass(frozen=True, kw_only=True)
class CaptureSetup:
    """What one run of the check renders.

    Attributes
    ----------
    mesh : str
        A mesh of ``pybullet_data`` (:data:`posevote.evaluation.rendering.MESHES`).
    photos : int
        Photographs of the object on the board.
    tests : int
        Test renders off the board, on clutter.
    seed : int
        Photograph and test draws.
    """

    mesh: str = "duck_vhacd.urdf"
    photos: int = 36
    tests: int = 24
    seed: int = 0

    def __post_init__(self) -> None:
        from posevote.evaluation.rendering import MESHES

        if self.mesh not in MESHES:
            raise ValueError(f"mesh must be one of {sorted(MESHES)}, got {self.mesh!r}")
        if not (isinstance(self.photos, int) and 6 <= self.photos <= 500):
            raise ValueError(f"photos must be an integer from 6 to 500, got {self.photos!r}")
        if not (isinstance(self.tests, int) and 1 <= self.tests <= 1000):
            raise ValueError(f"tests must be an integer from 1 to 1000, got {self.tests!r}")
        if not (isinstance(self.seed, int) and 0 <= self.seed < 2**31):
            raise ValueError(f"seed must be a non-negative integer, got {self.seed!r}")


def footprint(setup: CaptureSetup) -> Footprint:
    """What the user says of the object: standing on the board's centre, a cylinder a
    little larger than it (:data:`ROUGH`)."""
    from posevote.evaluation.rendering import MESHES, mesh_size

    extent = mesh_size(setup.mesh, MESHES[setup.mesh])
    width, height = BOARD.size_m
    return Footprint(centre_m=(width / 2, height / 2),
                     radius_m=ROUGH * float(np.hypot(extent[0], extent[1])) / 2,
                     height_m=ROUGH * float(extent[2]))


def draw_pose(rng: np.random.Generator, azimuth_deg: float, foot: Footprint, *,
              inplane_deg: tuple[float, float] = INPLANE_DEG
              ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A hand-held camera's ``R_cam_obj``, ``t_cam_obj`` (object frame on the footprint's
    centre) at this azimuth: elevation, in-plane angle, distance and the object's place in
    the frame drawn."""
    pose = np.radians([azimuth_deg, rng.uniform(*ELEVATION_DEG), rng.uniform(*inplane_deg)])
    R = rotation_from_pose(*pose)
    centre = np.array([0.0, 0.0, foot.height_m / 2])
    shift = np.append(rng.uniform(-OFF_AXIS_M, OFF_AXIS_M, 2), rng.uniform(*DISTANCE_M))
    return R, shift - R @ centre


def board_pose(R_cam_obj: NDArray[np.float64], t_cam_obj: NDArray[np.float64], foot: Footprint
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The board's ``R_cam_board``, ``t_cam_board`` of an object pose on the footprint."""
    R = R_cam_obj @ R_BOARD_OBJ.T
    return R, t_cam_obj - R @ np.array([foot.centre_m[0], foot.centre_m[1], 0.0])


def distort(image: NDArray[Any], camera: Camera = LENS) -> NDArray[Any]:
    """An ideal pinhole image as seen through ``camera``'s lens distortion."""
    h, w = image.shape[:2]
    grid = np.stack(np.meshgrid(np.arange(float(w)), np.arange(float(h))), axis=-1)
    maps = cv2.undistortPoints(grid.reshape(-1, 1, 2), camera.K, np.asarray(camera.dist),
                               P=camera.K).reshape(h, w, 2).astype(np.float32)
    return np.asarray(cv2.remap(image, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_REPLICATE))


def _board_layer(R: NDArray[np.float64], t: NDArray[np.float64]
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The printed board's grey levels and coverage in the ideal image (drawn at 4x and
    averaged down, as a sensor integrates its pixels)."""
    ppm = 4000.0
    # A white paper margin of 1 cm around the squares, as `posevote board` prints.
    margin = int(0.01 * ppm)
    paper = cv2.copyMakeBorder(squares_image(BOARD, ppm) * 255.0, margin, margin, margin, margin,
                               cv2.BORDER_CONSTANT, value=255)
    S = np.array([[1 / ppm, 0.0, -margin / ppm], [0.0, 1 / ppm, -margin / ppm], [0.0, 0.0, 1.0]])
    up = np.array([[4.0, 0.0, 1.5], [0.0, 4.0, 1.5], [0.0, 0.0, 1.0]])
    H = up @ LENS.K @ np.column_stack([R[:, 0], R[:, 1], t]) @ S
    fine = (4 * SIZE[0], 4 * SIZE[1])
    grey = cv2.warpPerspective(paper.astype(np.float32), H, fine)
    cover = cv2.warpPerspective(np.ones(paper.shape, np.float32), H, fine)
    return (cv2.resize(grey, SIZE, interpolation=cv2.INTER_AREA).astype(np.float64),
            cv2.resize(cover, SIZE, interpolation=cv2.INTER_AREA).astype(np.float64))


def _render(poses: list[tuple[NDArray[np.float64], NDArray[np.float64]]], mesh: str
            ) -> list[tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.float64]]]:
    """The object at each pose, drawn at 2x and averaged down: colour (RGB, 0..255), its
    mask and its coverage."""
    from posevote.evaluation.rendering import MESHES, render_posed

    fine = (2 * SIZE[0], 2 * SIZE[1])
    # pixel centres: 2 (u + 1/2) - 1/2 in the finer image
    intrinsics = (2 * LENS.fx, 2 * LENS.fy, 2 * LENS.cx + 0.5, 2 * LENS.cy + 0.5)
    with contextlib.redirect_stdout(io.StringIO()):   # pybullet prints its build on stdout
        drawn = render_posed(poses, intrinsics=intrinsics, size=fine, mesh=mesh,
                             base_euler=MESHES[mesh])
    out = []
    for rgb, mask in drawn:
        cover = cv2.resize(mask.astype(np.float32), SIZE, interpolation=cv2.INTER_AREA)
        colour = cv2.resize(rgb.astype(np.float32), SIZE, interpolation=cv2.INTER_AREA)
        out.append((colour.astype(np.float64), cover >= 0.5, cover.astype(np.float64)))
    return out


def _table(rng: np.random.Generator) -> NDArray[np.float64]:
    """A cluttered table and room behind the board, colour (0..255)."""
    from posevote.evaluation.synthetic import clutter_background

    grey = clutter_background((SIZE[1], SIZE[0]), rng=rng)
    tint = rng.uniform(0.8, 1.1, 3)
    return np.clip(grey[..., None] * 255.0 * tint, 0, 255)


def photographs(setup: CaptureSetup, folder: str | Path) -> dict[str, dict[str, Any]]:
    """Render the photographs of the object on the board into ``folder`` (PNG, through the
    lens) and return the truth per file name: ``R``, ``t`` (object), ``box`` and ``mask`` (the
    undistorted camera's)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    foot = footprint(setup)
    rng = np.random.default_rng(setup.seed)
    azimuths = (np.arange(setup.photos) * 360.0 / setup.photos
                + rng.uniform(-5, 5, setup.photos)) % 360
    poses = [draw_pose(rng, float(a), foot, inplane_deg=PHOTO_INPLANE_DEG) for a in azimuths]
    truth: dict[str, dict[str, Any]] = {}
    from posevote.evaluation.plots import write_png

    for k, ((R, t), (colour, mask, cover)) in enumerate(zip(poses, _render(poses, setup.mesh),
                                                            strict=True)):
        grey, board_cover = _board_layer(*board_pose(R, t, foot))
        printed = INK + (PAPER - INK) * grey / 255.0
        image = _table(rng)
        image = image * (1 - board_cover[..., None]) + printed[..., None] * board_cover[..., None]
        image = image * (1 - cover[..., None]) + colour * cover[..., None]
        name = f"photo_{k:03d}.png"
        photo = distort(np.clip(image, 0, 255).astype(np.float32))
        write_png(folder / name, np.round(photo[..., ::-1]).astype(np.uint8))
        rr, cc = np.nonzero(mask)
        truth[name] = {"R": R, "t": t, "mask": mask,
                       "box": (float(cc.min()), float(rr.min()), float(np.ptp(cc) + 1),
                               float(np.ptp(rr) + 1))}
    return truth


def off_board_images(setup: CaptureSetup) -> list[dict[str, Any]]:
    """The object off the board, on clutter, through the lens (grey), with its true
    ``R_cam_obj`` and box: azimuths anywhere, elevations and tilts as the photographs'."""
    foot = footprint(setup)
    rng = np.random.default_rng(10_000 + setup.seed)
    poses = [draw_pose(rng, float(rng.uniform(0, 360)), foot) for _ in range(setup.tests)]
    out = []
    for (R, _t), (colour, mask, cover) in zip(poses, _render(poses, setup.mesh), strict=True):
        image = _table(rng) * (1 - cover[..., None]) + colour * cover[..., None]
        grey = distort(np.clip(image, 0, 255).astype(np.float32)) @ np.array([0.299, 0.587,
                                                                               0.114])
        rr, cc = np.nonzero(mask)
        out.append({"image": np.clip(grey / 255.0, 0, 1), "R": R,
                    "box": (float(cc.min()), float(rr.min()), float(np.ptp(cc) + 1),
                            float(np.ptp(rr) + 1))})
    return out


def _true_set(truth: dict[str, dict[str, Any]], folder: Path, out: Path, foot: Footprint) -> None:
    """A training folder of the same photographs undistorted with the true lens, with the
    true poses, boxes, masks, distances and origins."""
    from posevote.data.images import read_bgr8
    from posevote.data.training_set import TrainingSet, write_poses_csv
    from posevote.evaluation.plots import write_png
    from posevote.geometry import pose_from_rotation

    (out / "masks").mkdir(parents=True, exist_ok=True)
    poses, boxes, masks, distances, origins = [], [], [], [], []
    for name, item in truth.items():
        undistorted = LENS.undistort(read_bgr8(folder / name).astype(np.float64))
        write_png(out / name, np.round(np.clip(undistorted, 0, 255)).astype(np.uint8))
        write_png(out / "masks" / name, item["mask"].astype(np.uint8) * 255)
        poses.append(pose_from_rotation(item["R"]))
        boxes.append(item["box"])
        masks.append(out / "masks" / name)
        point = item["R"] @ np.array([0.0, 0.0, foot.height_m / 2]) + item["t"]
        distances.append(float(point[2]))
        origins.append(LENS.project(point))
    write_poses_csv(TrainingSet(images=tuple(out / n for n in truth), poses=np.array(poses),
                                boxes=np.array(boxes), masks=tuple(masks),
                                distances=np.array(distances), origins=np.array(origins)), out)
    plain = Camera(fx=LENS.fx, fy=LENS.fy, cx=LENS.cx, cy=LENS.cy, dist=LENS.dist)
    atomic_write_text(out / "camera.json", json.dumps(plain.to_dict(), indent=2) + "\n")


def _train(folder: Path) -> tuple[Any, Camera]:
    """The ``cluttered`` model of a training folder, its height from the distances and the
    folder's camera, as `posevote train FOLDER --camera FOLDER/camera.json` makes it."""
    from posevote.camera import read_camera
    from posevote.data import read_poses_csv
    from posevote.estimator import PoseEstimator

    ts = read_poses_csv(folder)
    camera = read_camera(folder / "camera.json")
    # Every test image gets its best pose: the check compares poses, not the threshold.
    est = PoseEstimator.from_preset(PRESET, min_score=0.0)
    est.fit(list(ts.images), ts.poses, boxes=ts.boxes, masks=list(ts.masks),
            object_height_m=ts.object_height_m(camera), origins=ts.origins)
    return est, camera


def _write_tests(tests: list[dict[str, Any]], folder: Path) -> None:
    """The test images as the camera gave them (PNG) and their truth (``truth.csv``: the
    rotation's azimuth, elevation and in-plane angle in degrees, the object's box)."""
    from posevote.evaluation.plots import write_png
    from posevote.geometry import pose_from_rotation

    folder.mkdir(parents=True, exist_ok=True)
    lines = ["image,azimuth_deg,elevation_deg,inplane_deg,box_x,box_y,box_w,box_h"]
    for k, item in enumerate(tests):
        name = f"test_{k:03d}.png"
        grey = np.round(item["image"] * 255).astype(np.uint8)
        write_png(folder / name, np.repeat(grey[..., None], 3, axis=2))
        pose = np.degrees(pose_from_rotation(item["R"]))
        pose[0], pose[2] = pose[0] % 360, (pose[2] + 180) % 360 - 180
        lines.append(",".join([name, *(f"{v:.3f}" for v in pose),
                               *(f"{v:.0f}" for v in item["box"])]))
    atomic_write_text(folder / "truth.csv", "\n".join(lines) + "\n")


def _iou(a: NDArray[np.bool_], b: NDArray[np.bool_]) -> float:
    return float(np.count_nonzero(a & b)) / max(float(np.count_nonzero(a | b)), 1.0)


def run_capture_check(setup: CaptureSetup, out: str | Path, *,
                      log: Callable[[str], None] = lambda _m: None) -> dict[str, Any]:
    """Render, capture, train and test (the module docstring); ``report.md`` and
    ``summary.json`` in ``out``, the photographs in ``out/photos``, the captured folder in
    ``out/captured``, the truth's in ``out/true``, the test images and their truth in
    ``out/tests``. Returns the summary."""
    from posevote.data import read_mask, read_poses_csv

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    foot = footprint(setup)
    log(f"rendering {setup.photos} photographs of {setup.mesh} on the board")
    truth = photographs(setup, out / "photos")
    log("capturing")
    report = capture(sorted((out / "photos").glob("*.png")), out / "captured", footprint=foot,
                     spec=BOARD)
    cam = report.camera
    ts = read_poses_csv(out / "captured")
    rotation, distance, box, mask = [], [], [], []
    for path, pose, b, m, d in zip(ts.images, ts.poses, ts.boxes, ts.masks, ts.distances,
                                   strict=True):
        item = truth[path.name]
        rotation.append(float(np.degrees(rotation_angle(rotation_from_pose(*pose), item["R"]))))
        point = item["R"] @ np.array([0.0, 0.0, foot.height_m / 2]) + item["t"]
        distance.append(100 * abs(d - point[2]) / point[2])
        box.append(box_iou(b, item["box"]))
        mask.append(_iou(read_mask(m), item["mask"]) if m is not None else 0.0)
    log("training on the captured folder and on the truth")
    (out / "true").mkdir(exist_ok=True)
    _true_set(truth, out / "photos", out / "true", foot)
    models = {"captured": _train(out / "captured"), "true": _train(out / "true")}
    tests = off_board_images(setup)
    _write_tests(tests, out / "tests")
    errors: dict[str, list[float]] = {name: [] for name in models}
    found: dict[str, list[bool]] = {name: [] for name in models}
    seconds: dict[str, list[float]] = {name: [] for name in models}
    for item in tests:
        for name, (est, camera) in models.items():
            tick = time.perf_counter()
            result = est.estimate(item["image"], camera=camera)
            seconds[name].append(time.perf_counter() - tick)
            best = result.best
            right = best is not None and best.R_cam_obj is not None
            errors[name].append(float(np.degrees(rotation_angle(best.R_cam_obj, item["R"])))
                                if right else 180.0)
            found[name].append(bool(right and box_iou(best.box, item["box"]) >= 0.5))
    summary: dict[str, Any] = {
        "mesh": setup.mesh, "photos": setup.photos, "kept": len(report.kept),
        "refused": [list(r) for r in report.refused], "seed": setup.seed,
        "calibration_rms_px": report.calibration_rms_px,
        "intrinsics_error_pct": {k: 100 * abs(getattr(cam, k) - getattr(LENS, k))
                                 / getattr(LENS, k) for k in ("fx", "fy", "cx", "cy")},
        "dist": list(cam.dist), "true_dist": list(LENS.dist),
        "rotation_deg": {"median": float(np.median(rotation)), "max": float(np.max(rotation))},
        "distance_pct": {"median": float(np.median(distance)), "max": float(np.max(distance))},
        "box_iou": {"median": float(np.median(box)), "min": float(np.min(box))},
        "mask_iou": {"median": float(np.median(mask)), "min": float(np.min(mask)),
                     "masked": int(sum(m is not None for m in ts.masks))},
        "tests": setup.tests, "preset": PRESET,
        "models": {name: {"median_deg": float(np.median(errors[name])),
                          "mean_deg": float(np.mean(errors[name])),
                          "under_30_pct": 100 * float(np.mean(np.array(errors[name]) < 30)),
                          "found_pct": 100 * float(np.mean(found[name])),
                          "seconds": float(np.mean(seconds[name]))} for name in models},
        "errors_deg": errors, "wall_seconds": time.perf_counter() - start}
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    atomic_write_text(out / "report.md", report_text(summary))
    return summary


def report_text(summary: dict[str, Any]) -> str:
    """The check's report (markdown)."""
    i, m = summary["intrinsics_error_pct"], summary["models"]
    ratio = m["captured"]["median_deg"] / max(m["true"]["median_deg"], 1e-9)
    lines = [
        f"# Rendered capture check: {summary['mesh']} on the board",
        "",
        f"{summary['kept']} of {summary['photos']} photographs kept (seed {summary['seed']}); "
        f"refused: {len(summary['refused'])}.",
        "",
        "| what | captured vs truth |",
        "|---|---|",
        f"| calibration RMS | {summary['calibration_rms_px']:.3f} px |",
        f"| fx, fy, cx, cy | {i['fx']:.2f}, {i['fy']:.2f}, {i['cx']:.2f}, {i['cy']:.2f} % off |",
        f"| distortion | {', '.join(f'{d:.4f}' for d in summary['dist'][:2])} (true "
        f"{', '.join(f'{d:.4f}' for d in summary['true_dist'][:2])}) |",
        f"| rotation | median {summary['rotation_deg']['median']:.2f}, max "
        f"{summary['rotation_deg']['max']:.2f} deg |",
        f"| distance | median {summary['distance_pct']['median']:.2f}, max "
        f"{summary['distance_pct']['max']:.2f} % |",
        f"| box IoU | median {summary['box_iou']['median']:.3f}, min "
        f"{summary['box_iou']['min']:.3f} |",
        f"| mask IoU | median {summary['mask_iou']['median']:.3f}, min "
        f"{summary['mask_iou']['min']:.3f} ({summary['mask_iou']['masked']} masked) |",
        "",
        f"Test: {summary['tests']} renders off the board on clutter, through the lens, "
        f"`{summary['preset']}` preset.",
        "",
        "| trained on | median | mean | < 30 deg | found (IoU >= 0.5) | s / image |",
        "|---|---|---|---|---|---|",
    ]
    for name in ("captured", "true"):
        r = m[name]
        lines.append(f"| {name} | {r['median_deg']:.2f} | {r['mean_deg']:.2f} | "
                     f"{r['under_30_pct']:.0f}% | {r['found_pct']:.0f}% | {r['seconds']:.2f} |")
    lines += ["", f"Median rotation error, captured over true: {ratio:.2f}x.", ""]
    return "\n".join(lines)
