"""Cross-validation of the category-level settings on COIL training views only.

For each COIL category of Fig. 5, the seen instances' 18 training views (0,
20, ..., 340 degrees) are split in 3 folds (fold r holds out the views whose
index is r modulo 3); a category model is trained on the other 12 views of
every seen instance and tested on the held-out 6. The protocol's test views
(5, 10, 15, ... degrees off the training views) and the unseen instances
are never used. Prints median / mean error and the recognition rate per
category for each setting.

Usage::

    python benchmarks/tune_category_cv.py --param instance_margin=1.0 --param instance_margin=1.1
        [--markdown docs/results/tuning_category_cv.md]
"""

from __future__ import annotations

import argparse
import ast
import os
import shlex
import sys
from pathlib import Path

import numpy as np

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from posevote import PoseEstimator  # noqa: E402
from posevote.data import read_coil  # noqa: E402
from posevote.evaluation.protocols import COIL_CATEGORIES  # noqa: E402
from posevote.evaluation.runner import pose_error_deg  # noqa: E402


def run(data: Path, params: dict) -> dict[str, tuple[float, float, float]]:
    views = list(range(0, 360, 20))
    out = {}
    for cat, (seen, _unseen, half) in COIL_CATEGORIES.items():
        errors, right = [], []
        for r in range(3):
            train = read_coil(data, objects=seen,
                              azimuths_deg=[a for i, a in enumerate(views) if i % 3 != r])
            test = read_coil(data, objects=seen, azimuths_deg=views[r::3])
            est = PoseEstimator(**params).fit(train.images, train.poses, boxes=train.boxes,
                                              instances=list(train.instances))
            for image, pose, inst in zip(test.images, test.poses, test.instances, strict=True):
                res = est.estimate(image)
                errors.append(pose_error_deg(res.best.azimuth, pose[0], half_turn=half))
                right.append(res.instance == inst)
        out[cat] = (float(np.median(errors)), float(np.mean(errors)), 100.0 * float(np.mean(right)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path,
                        default=Path(__file__).resolve().parents[2] / "shared" / "data" / "coil-100")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                        help="one setting per --param (each is a row; none: the defaults)")
    parser.add_argument("--markdown", type=Path)
    args = parser.parse_args()
    settings = [{}] if not args.param else [
        {p.split("=", 1)[0]: ast.literal_eval(p.split("=", 1)[1])} for p in args.param]
    lines = ["Command: `python " + " ".join(shlex.quote(a) for a in sys.argv) + "`", "",
             "| setting | " + " | ".join(f"{c} median / mean / recognised %"
                                         for c in COIL_CATEGORIES) + " | sum of medians "
             "| sum of means |", "|---|" + "---|" * (len(COIL_CATEGORIES) + 2)]
    for params in settings:
        res = run(args.data, params)
        cells = " | ".join(f"{m:.2f} / {a:.2f} / {r:.0f}" for m, a, r in res.values())
        line = (f"| {params or 'defaults'} | {cells} | {sum(v[0] for v in res.values()):.2f} "
                f"| {sum(v[1] for v in res.values()):.2f} |")
        print(line, flush=True)
        lines.append(line)
    if args.markdown:
        args.markdown.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
