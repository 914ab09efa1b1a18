"""Diagnostic: the epfl-cv pipeline when the car's true box is given.

Each test frame of ``epfl-cv`` (cars 1-5 train / 6-10 test and back; cars
11-20 are never read) is cropped to its true box grown by ``--margin`` of
its size on every side, and the category model of the main row
(the ``category`` preset) estimates the pose in the
crop. Compared with the same frames in full (``benchmarks/tune_epfl.py``),
this separates what finding the car costs from what estimating its pose
inside the box costs. ``--no-verify`` switches the appearance verification
off (the edge search alone picks the viewpoint). Prints median / mean
error, % under 22.5 and 45 degrees.

Usage::

    python benchmarks/epfl_true_box.py [--data ../shared/data] [--every 8] [--margin 0.25]
        [--no-verify] [--jobs 2]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from posevote import PoseEstimator  # noqa: E402
from posevote.data import read_image  # noqa: E402
from posevote.evaluation.protocols import epfl_cv  # noqa: E402
from posevote.evaluation.runner import pose_error_deg  # noqa: E402


def run_part(data: str, split: int, part: int, n_parts: int, every: int, margin: float,
             verify: bool) -> list[float]:
    """Errors (degrees) of one share of one split's every-th test frames."""
    sp = epfl_cv(data).splits[split]
    est = PoseEstimator.from_preset("category", **({} if verify else {"appearance__candidates": 0}))
    est.fit(sp.train.images, sp.train.poses, boxes=sp.train.boxes,
                                      instances=list(sp.train.instances))
    errors = []
    for i in list(range(0, len(sp.test.images), every))[part::n_parts]:
        img = read_image(sp.test.images[i])
        x, y, w, h = sp.test.boxes[i]
        x0, y0 = int(max(0, x - margin * w)), int(max(0, y - margin * h))
        x1 = int(min(img.shape[1], x + (1 + margin) * w))
        y1 = int(min(img.shape[0], y + (1 + margin) * h))
        result = est.estimate(img[y0:y1, x0:x1])
        errors.append(180.0 if result.best is None else
                      pose_error_deg(result.best.azimuth, sp.test.poses[i][0], half_turn=False))
    return errors


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared"
                                              / "data"))
    parser.add_argument("--every", type=int, default=8)
    parser.add_argument("--margin", type=float, default=0.25)
    parser.add_argument("--no-verify", action="store_true")
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    tasks = [(s, k) for s in (0, 1) for k in range(args.jobs)]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        parts = list(pool.map(run_part, [args.data] * len(tasks), [s for s, _ in tasks],
                              [k for _, k in tasks], [args.jobs] * len(tasks),
                              [args.every] * len(tasks), [args.margin] * len(tasks),
                              [not args.no_verify] * len(tasks)))
    e = np.array([x for p in parts for x in p])
    print(f"true box grown by {args.margin:g}, verification {'off' if args.no_verify else 'on'}, "
          f"every {args.every}th frame: n {len(e)}, median {np.median(e):.2f}, mean {e.mean():.2f}, "
          f"< 22.5 {100 * np.mean(e < 22.5):.1f}%, < 45 {100 * np.mean(e < 45):.1f}% "
          f"({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
