"""Settings sweep for the EPFL category protocols, on epfl-cv (cars 1-10 only).

Runs the "weights + fitting" row of ``posevote evaluate epfl-cv`` (cars
1-5 train / 6-10 test, then the other way round; full frames) on every
``--every``-th test frame, with ``EPFL_PARAMS`` plus the settings given, and
prints one line per setting: median, mean, % under 45 degrees, detection
rate, seconds per frame. Cars 11-20 (the held-out test set) are never read.
This is how ``EPFL_CATEGORY_PARAMS`` was chosen (docs/TUNING.md).

Usage::

    python benchmarks/tune_epfl_cv.py [--every 8] [--setting "density_cap=0.5 position_sigma=6.0" ...]
"""

from __future__ import annotations

import argparse
import ast
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from posevote import PoseEstimator  # noqa: E402
from posevote.evaluation.metrics import box_iou  # noqa: E402
from posevote.evaluation.protocols import EPFL_PARAMS, load_protocol  # noqa: E402
from posevote.evaluation.runner import pose_error_deg  # noqa: E402


def run_fold(data: str, fold: int, every: int, overrides: dict) -> list[tuple[float, float, float]]:
    """(error in degrees, IoU, seconds) for every ``every``-th test frame of one fold."""
    split = load_protocol("epfl-cv", data).splits[fold]
    est = PoseEstimator(**{**EPFL_PARAMS, **overrides})
    est.fit(split.train.images, split.train.poses, boxes=split.train.boxes,
            instances=list(split.train.instances))
    out = []
    for i in range(0, len(split.test.images), every):
        res = est.estimate(split.test.images[i])
        if res.best is None:
            out.append((180.0, 0.0, res.seconds))
            continue
        out.append((pose_error_deg(res.best.azimuth, split.test.poses[i, 0], half_turn=False),
                    float(box_iou(res.best.box, split.test.boxes[i])), res.seconds))
    return out


def parse_setting(text: str) -> dict:
    """``"a=1 b=(2, 3)"`` -> ``{"a": 1, "b": (2, 3)}``; items separated by spaces."""
    out = {}
    for item in text.split():
        name, _, value = item.partition("=")
        out[name] = ast.literal_eval(value)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared"
                                              / "data"))
    parser.add_argument("--every", type=int, default=8)
    parser.add_argument("--setting", action="append", default=[],
                        help="space-separated NAME=VALUE items; one line per --setting "
                             "(none: EPFL_PARAMS alone)")
    args = parser.parse_args(argv)
    for text in args.setting or [""]:
        overrides = parse_setting(text)
        start = time.perf_counter()
        with ProcessPoolExecutor(max_workers=2) as pool:
            parts = list(pool.map(run_fold, [args.data] * 2, [0, 1], [args.every] * 2,
                                  [overrides] * 2))
        res = np.array([r for part in parts for r in part])
        err, iou, sec = res[:, 0], res[:, 1], res[:, 2]
        print(f"{overrides or 'EPFL_PARAMS'}: n={len(err)} median {np.median(err):.1f} "
              f"mean {err.mean():.1f} <45 {100 * np.mean(err < 45):.1f}% "
              f"detected {100 * np.mean(iou >= 0.5):.1f}% s/img {np.median(sec):.2f} "
              f"wall {time.perf_counter() - start:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
