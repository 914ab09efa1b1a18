"""A BOP round trip on rendered views (issue 28): written, read back, trained, estimated, scored.

The rendered sphere's training views (pybullet's r2d2, or ``--mesh``, on black, azimuth
every 20 degrees at elevations -30 to 60) and ``--images`` test views at
random azimuths and elevations are written as two BOP scenes, with the
renderer's camera and, as ``cam_t_m2c``, where the mesh's origin lies in the
camera frame. The training scene is read back and trained on (``default``
preset, the object's height from the scene's distances, the origin's image and
depth factor in each view), each test image is estimated with its camera and the results CSV
is written as ``posevote bop`` writes it; the CSV is then read and scored
against the test scene's ground truth: the geodesic rotation error and the
translation error as a share of the depth. The same with a model trained
without the origins (``t`` then names the box centre) shows what they give.

Usage::

    python benchmarks/bop_round_trip.py [--mesh r2d2.urdf] [--images 40] [--seed 0] [--out DIR]
        [--markdown FILE]
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from _markdown import emit  # noqa: E402

from posevote import PoseEstimator  # noqa: E402
from posevote.batch import estimate_bop_scene  # noqa: E402
from posevote.camera import Camera  # noqa: E402
from posevote.data.bop import read_bop_scene, write_bop_results, write_bop_scene  # noqa: E402
from posevote.evaluation.rendering import MESHES, render_focal, render_turntable  # noqa: E402
from posevote.evaluation.sphere import AZIMUTH_STEP_DEG, ELEVATIONS_DEG, SIZE  # noqa: E402
from posevote.geometry import rotation_angle, rotation_from_pose  # noqa: E402


def _render(azimuths_rad: list[float], elevation_deg: float, mesh: str) -> list:
    # pybullet prints its build time on stdout when it connects.
    with contextlib.redirect_stdout(io.StringIO()):
        return render_turntable(np.asarray(azimuths_rad), size=SIZE, elevation_deg=elevation_deg,
                                distance=None, mesh=mesh, base_euler=MESHES[mesh])


def _write(folder: Path, views: list, elevations: list[float], camera: Camera) -> Path:
    return write_bop_scene(
        folder, [(v.image * 255).round().astype(np.uint8) for v in views],
        [rotation_from_pose(v.azimuth, np.radians(el), 0.0) for v, el in zip(views, elevations,
                                                                              strict=True)],
        [v.origin for v in views], camera, obj_id=1, boxes=[v.box for v in views],
        masks=[v.mask for v in views])


def _score(csv_path: Path, truth: list) -> tuple[np.ndarray, np.ndarray]:
    """Per test image: the rotation error (degrees) and the translation error (x, y, z) as
    shares of the true depth (an image without a row: 180 and infinity)."""
    rows = list(csv.DictReader(io.StringIO(csv_path.read_text())))
    rot, trans = np.full(len(truth), 180.0), np.full((len(truth), 3), np.inf)
    for row in rows:
        k = int(row["im_id"])
        R = np.array(row["R"].split(), dtype=float).reshape(3, 3)
        t = np.array(row["t"].split(), dtype=float) / 1000.0
        R_true, t_true = truth[k]
        rot[k] = np.degrees(rotation_angle(R, R_true))
        trans[k] = 100.0 * (t - t_true) / t_true[2]
    return rot, trans


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mesh", default="r2d2.urdf", choices=sorted(MESHES))
    ap.add_argument("--images", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", help="folder for the scenes and CSVs (default: a temporary one)")
    ap.add_argument("--markdown", help="also write the report here")
    args = ap.parse_args(argv)
    if not 1 <= args.images <= 1000:
        ap.error("--images must be in [1, 1000]")
    focal = render_focal(SIZE)
    camera = Camera(fx=focal, fy=focal, cx=(SIZE - 1) / 2.0, cy=(SIZE - 1) / 2.0)
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out or tmp)
        train_views, train_els = [], []
        for el in ELEVATIONS_DEG:
            views = _render(list(np.radians(np.arange(0, 360, AZIMUTH_STEP_DEG))), el, args.mesh)
            train_views += views
            train_els += [el] * len(views)
        test_views, test_els = [], []
        for _ in range(args.images):
            el = float(rng.uniform(min(ELEVATIONS_DEG), max(ELEVATIONS_DEG)))
            test_views += _render([float(rng.uniform(0.0, 2 * np.pi))], el, args.mesh)
            test_els.append(el)
        train_scene = _write(out / "train" / "000001", train_views, train_els, camera)
        test_scene = _write(out / "test" / "000002", test_views, test_els, camera)
        truth = [(rotation_from_pose(v.azimuth, np.radians(el), 0.0), v.origin)
                 for v, el in zip(test_views, test_els, strict=True)]
        read = read_bop_scene(train_scene, obj_id=1)
        ts = read.training_set
        height = ts.object_height_m(read.cameras)
        lines = [f"BOP round trip, {args.mesh}: {len(ts)} training views written and read back, "
                 f"{args.images} test views (random azimuth, elevation "
                 f"{min(ELEVATIONS_DEG):g} to {max(ELEVATIONS_DEG):g} deg, on black), "
                 f"`default` preset, seed {args.seed}", "",
                 "| model | rotation median ° | % < 10° | translation median (% of depth) | "
                 "% translation < 2% | across (x, y) median % | depth (z) median % | "
                 "s / image |", "|---|---|---|---|---|---|---|---|"]
        for name, origins in (("with the origins (t names the mesh origin)", ts.origins),
                              ("without them (t names the box centre)", None)):
            est = PoseEstimator.from_preset("default", min_score=0.0).fit(
                [str(p) for p in ts.images], ts.poses, boxes=ts.boxes, masks=list(ts.masks),
                object_height_m=height, origins=origins)
            start = time.perf_counter()
            rows = estimate_bop_scene(est, test_scene, obj_id=1)
            seconds = (time.perf_counter() - start) / args.images
            results = out / f"results_{'origin' if origins is not None else 'centre'}.csv"
            write_bop_results(results, rows)
            rot, err = _score(results, truth)
            whole = np.linalg.norm(err, axis=1)
            lines.append(f"| {name} | {np.median(rot):.2f} | {100 * np.mean(rot < 10):.1f} | "
                         f"{np.median(whole):.2f} | {100 * np.mean(whole < 2):.1f} | "
                         f"{np.median(np.hypot(err[:, 0], err[:, 1])):.2f} | "
                         f"{np.median(err[:, 2]):+.2f} | {seconds:.3f} |")
    lines += ["", f"Wall time {time.perf_counter() - t0:.0f} s."]
    text = "\n".join(lines) + "\n"
    return emit(text, args.markdown, __file__, argv, fenced=False)


if __name__ == "__main__":
    sys.exit(main())
