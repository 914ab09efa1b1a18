"""posevote's time per image beside OpenCV LINE-2D's, on one thread, with the targets of issue 27.

In one run on this machine:

- EPFL full frames (every ``--every``-th frame of cars 1-10, as stand-ins for
  the held-out cars 11-20: the same camera, size and kind of scene), the
  ``category`` preset's model of cars 1-10 (its training time too, on one
  thread and with a thread per core), and
  LINE-2D (``cv2.linemod``, one template per training frame at scales 0.8,
  1.0 and 1.2, the box as its mask) on the same frames. opencv-contrib
  replaces the project's OpenCV, so LINE-2D runs in a virtual environment of
  its own that this script creates (``--venv``; ``benchmarks/_line2d.py``).
- COIL-100 clean views with the ``default`` preset (object 1, views every 20
  degrees trained, the views between them tested).
- COIL-100 views pasted on 256 x 256 clutter with the ``cluttered`` preset.

Only time is printed (the stand-ins are training frames); the accuracy of
each change is measured by the protocols.

Usage::

    python benchmarks/speed.py [--data ../shared/data] [--every 16] [--no-line2d]
        [--venv DIR] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from _markdown import emit  # noqa: E402

from posevote import PoseEstimator  # noqa: E402
from posevote.data import read_coil, read_epfl  # noqa: E402
from posevote.evaluation.protocols import _epfl_folder, _find  # noqa: E402
from posevote.evaluation.synthetic import paste_on_clutter  # noqa: E402

# One thread for OpenCV too (its resizes and blurs), as LINE-2D gets.
cv2.setNumThreads(1)

#: Issue 27's targets, seconds.
TARGETS = {"epfl": 0.1, "coil": 0.010, "clutter": 0.3, "train": 15.0}
LINE2D_SCALES = (0.8, 1.0, 1.2)
LINE2D_THRESHOLD = 80.0
LINE2D_PACKAGE = "opencv-contrib-python-headless<5"  # 5.x crashes in linemod's match


def _median_seconds(est: PoseEstimator, images: list) -> float:
    est.estimate(images[0])  # compile and warm the caches
    seconds = []
    for image in images:
        start = time.perf_counter()
        est.estimate(image)
        seconds.append(time.perf_counter() - start)
    return float(np.median(seconds))


def _line2d(venv: Path, train: list[str], boxes: list, test: list[str]) -> dict:
    python = venv / "bin" / "python"
    if not python.is_file():
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        subprocess.run([str(python), "-m", "pip", "install", "-q", LINE2D_PACKAGE, "numpy"],
                       check=True)
    with tempfile.TemporaryDirectory() as tmp:
        job = Path(tmp) / "job.json"
        job.write_text(json.dumps({"train": train, "boxes": boxes, "test": test,
                                   "scales": list(LINE2D_SCALES),
                                   "threshold": LINE2D_THRESHOLD}))
        out = subprocess.run([str(python), str(Path(__file__).with_name("_line2d.py")),
                              str(job)], check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    ap.add_argument("--every", type=int, default=16, help="time every N-th EPFL frame")
    ap.add_argument("--no-line2d", action="store_true", help="skip LINE-2D")
    ap.add_argument("--venv", default=str(Path.home() / ".cache" / "posevote" / "line2d-venv"),
                    help="LINE-2D's virtual environment (created when missing)")
    ap.add_argument("--markdown", help="also write the printed report here")
    args = ap.parse_args(argv)
    cars = read_epfl(_epfl_folder(args.data), cars=list(range(1, 11)))
    start = time.perf_counter()
    est = PoseEstimator.from_preset("category", min_score=0.0).fit(
        cars.images, cars.poses, boxes=cars.boxes, instances=list(cars.instances),
        category=cars.category)
    train_s = time.perf_counter() - start
    cores = os.cpu_count() or 1
    start = time.perf_counter()
    PoseEstimator.from_preset("category", n_jobs=cores).fit(
        cars.images, cars.poses, boxes=cars.boxes, instances=list(cars.instances),
        category=cars.category)
    train_threads_s = time.perf_counter() - start
    frames = [str(p) for p in cars.images[1::args.every]]
    epfl_s = _median_seconds(est, frames)
    line2d = None if args.no_line2d else _line2d(
        Path(args.venv), [str(p) for p in cars.images], cars.boxes.tolist(), frames)

    coil = _find(Path(args.data), "coil-100")
    train = read_coil(coil, objects=[1], azimuths_deg=list(range(0, 360, 20)))
    test = read_coil(coil, objects=[1], azimuths_deg=[a for a in range(0, 360, 5) if a % 20])
    views, boxes = train.load_images(), train.boxes
    clean = PoseEstimator.from_preset("default").fit(views, train.poses, boxes=boxes)
    coil_s = _median_seconds(clean, test.load_images())
    rng = np.random.default_rng(0)
    pasted = [paste_on_clutter(img, box, rng=rng).image
              for img, box in list(zip(test.load_images(), test.boxes, strict=True))[::6]]
    clutter = PoseEstimator.from_preset("cluttered").fit(views, train.poses, boxes=boxes)
    clutter_s = _median_seconds(clutter, pasted)

    report = io.StringIO()
    with contextlib.redirect_stdout(report):
        print(f"one thread, {os.cpu_count()} cores; median seconds per image")
        print(f"{'measure':<58}{'seconds':>9}{'target':>9}{'x target':>10}")
        rows = [(f"EPFL frame, category preset, 10 cars ({len(frames)} frames)", epfl_s, "epfl"),
                (f"COIL clean view, default preset ({len(test.images)} views)", coil_s, "coil"),
                (f"COIL view in 256 x 256 clutter, cluttered preset ({len(pasted)})",
                 clutter_s, "clutter"),
                (f"training the 10-car category model ({len(cars.images)} frames)", train_s,
                 "train"),
                (f"  the same, n_jobs={cores} (threads reading the images)", train_threads_s,
                 "train")]
        for name, value, key in rows:
            print(f"{name:<58}{value:>9.4f}{TARGETS[key]:>9.3f}{value / TARGETS[key]:>10.2f}")
        if line2d is not None:
            l2d = float(np.median(line2d["seconds"]))
            print(f"LINE-2D (OpenCV {line2d['opencv']}, {line2d['templates']} templates) "
                  f"{l2d:.3f} s per frame on the same frames; posevote / LINE-2D = "
                  f"{epfl_s / l2d:.2f} (target <= 0.33)")
    return emit(report.getvalue(), args.markdown, __file__, argv)


if __name__ == "__main__":
    raise SystemExit(main())
