"""How much the fit's tolerance moves the estimates (docs/history/TUNING.md, "Fit tolerance").

On the clean COIL cross-validation (``coil_instance.py --cv``: the 18
training views of each of the 16 objects, 3 folds, never the protocol's
test views), every held-out view is probed once and its modes are fitted at
each tolerance given; prints the change of the best mode's azimuth against
the first tolerance, and the median / mean error and fitting time of each.

Usage::

    python benchmarks/fit_tolerance.py [--tolerances 1e-8,1e-4] [--objects 1,6,...]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from coil_instance import HALF_TURN, OBJECTS, splits  # noqa: E402

from posevote import PoseEstimator  # noqa: E402
from posevote.data import read_coil  # noqa: E402
from posevote.geometry import angular_error  # noqa: E402
from posevote.refinement.fitting import find_modes, refine_mode  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[1].parent
                                          / "shared/data/coil-100"))
    ap.add_argument("--tolerances", default="1e-8,1e-4")
    ap.add_argument("--objects", default=",".join(map(str, OBJECTS)))
    args = ap.parse_args(argv)
    tols = [float(t) for t in args.tolerances.split(",")]
    errors: dict[float, list[float]] = {t: [] for t in tols}
    seconds = dict.fromkeys(tols, 0.0)
    moved = []
    for obj in (int(o) for o in args.objects.split(",")):
        period = np.pi if obj in HALF_TURN else 2 * np.pi
        for train_az, test_az in splits("cv"):
            train = read_coil(args.data, objects=[obj], azimuths_deg=train_az)
            test = read_coil(args.data, objects=[obj], azimuths_deg=test_az)
            est = PoseEstimator().fit(train.load_images(), train.poses, boxes=train.boxes)
            for image, pose in zip(test.load_images(), test.poses, strict=True):
                probes, _ = est.probe(image)
                modes = find_modes(probes, max_modes=est.max_modes)
                if not modes:
                    continue
                azimuths = []
                for t in tols:
                    start = time.perf_counter()
                    best = [refine_mode(probes, v, tolerance=t) for v in modes][0]
                    seconds[t] += time.perf_counter() - start
                    azimuths.append(best.azimuth)
                    errors[t].append(float(np.degrees(angular_error(best.azimuth, pose[0],
                                                                    period=period))))
                moved.append([np.degrees(angular_error(a, azimuths[0])) for a in azimuths])
    d = np.array(moved)
    print(f"{len(d)} held-out views; change of the best azimuth against tolerance {tols[0]:g}:")
    for k, t in enumerate(tols):
        print(f"  tolerance {t:g}: change median {np.median(d[:, k]):.4f} p99 "
              f"{np.percentile(d[:, k], 99):.3f} max {d[:, k].max():.3f} deg; error median "
              f"{np.median(errors[t]):.2f} mean {np.mean(errors[t]):.2f} deg; fitting "
              f"{seconds[t]:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
