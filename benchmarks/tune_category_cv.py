"""Cross-validation of the category-level settings on COIL training views only.

For each COIL category of Fig. 5, the seen instances' 18 training views (0,
20, ..., 340 degrees) are split in 3 folds (fold r holds out the views whose
index is r modulo 3); a category model is trained on the other 12 views of
every seen instance and tested on the held-out 6. The protocol's test views
(5, 10, 15, ... degrees off the training views) and the unseen instances
are never used. Prints median / mean error and the recognition rate per
category for each setting.

``--margins`` studies ``instance_margin`` on seen *and* unseen instances in
one pass: besides the 3-fold CV above, each seen instance of a category in
turn is left out of the category model (trained on the other seen
instances' 18 training views) and its 18 training views are tested, so the
instance is unseen. Every image is estimated once with the category model
alone and once refined with the recognised instance; the error under a
margin ``m`` is the refined one when the recognition margin is at least
``m`` and the category one otherwise. Flat bottles have only two seen
instances, so their leave-one-out model holds one instance and never
refines: they enter the seen part only. The models are pruned with the
``moderate`` preset, as in the protocol's "refined with instance model" row.
With ``--param`` settings, the study is repeated for each of them.

Usage::

    python benchmarks/tune_category_cv.py --param recognition.margin=1.0 --param recognition.margin=1.1
        [--markdown docs/results/tuning_category_cv.md]
    python benchmarks/tune_category_cv.py --margins 1.0,1.1,1.25,1.5,inf
        [--param recognition.search=False ...] [--markdown docs/results/tuning_instance_margin.md]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import shlex
import sys
from pathlib import Path

import numpy as np

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from _settings import parse_settings  # noqa: E402

from posevote import PoseEstimator  # noqa: E402
from posevote.data import read_coil  # noqa: E402
from posevote.evaluation.protocols import COIL_CATEGORIES  # noqa: E402
from posevote.evaluation.runner import pose_error_deg  # noqa: E402
from posevote.recognition import RecognitionOptions


def run(data: Path, params: dict) -> dict[str, tuple[float, float, float]]:
    views = list(range(0, 360, 20))
    out = {}
    for cat, (seen, _unseen, half) in COIL_CATEGORIES.items():
        errors, right = [], []
        for r in range(3):
            train = read_coil(data, objects=seen,
                              azimuths_deg=[a for i, a in enumerate(views) if i % 3 != r])
            test = read_coil(data, objects=seen, azimuths_deg=views[r::3])
            est = PoseEstimator.from_preset("default", **{"min_score": 0.0, **params}).fit(
                train.images, train.poses, boxes=train.boxes, instances=list(train.instances))
            for image, pose, inst in zip(test.images, test.poses, test.instances, strict=True):
                res = est.estimate(image)
                errors.append(pose_error_deg(res.best.azimuth, pose[0], half_turn=half))
                right.append(res.instance == inst)
        out[cat] = (float(np.median(errors)), float(np.mean(errors)), 100.0 * float(np.mean(right)))
    return out


def margin_records(data: Path, params: dict | None = None) -> list[dict]:
    """Per test image: category error, refined error, margin, for seen and unseen instances."""
    views = list(range(0, 360, 20))
    folds = []
    for cat, (seen, _unseen, half) in COIL_CATEGORIES.items():
        for r in range(3):
            folds.append((cat, half, "seen", seen,
                          [a for i, a in enumerate(views) if i % 3 != r], seen, views[r::3]))
        if len(seen) > 2:
            for held in seen:
                rest = [o for o in seen if o != held]
                folds.append((cat, half, "unseen", rest, views, [held], views))
    records = []
    for cat, half, kind, train_objs, train_az, test_objs, test_az in folds:
        train = read_coil(data, objects=train_objs, azimuths_deg=train_az)
        test = read_coil(data, objects=test_objs, azimuths_deg=test_az)
        est = PoseEstimator.from_preset("default", **{"min_score": 0.0, "prune": "moderate",
                                                       **(params or {})})
        recognition = dataclasses.replace(est.recognition or RecognitionOptions(), margin=1.0)
        est.fit(train.images, train.poses, boxes=train.boxes, instances=list(train.instances))
        for image, pose in zip(test.images, test.poses, strict=True):
            refined = est.set_params(recognition=recognition).estimate(image)
            plain = est.set_params(recognition=None).estimate(image)
            records.append({
                "category": cat, "kind": kind,
                "plain": pose_error_deg(plain.best.azimuth, pose[0], half_turn=half),
                "refined": pose_error_deg(refined.best.azimuth, pose[0], half_turn=half),
                "margin": refined.instance_margin})
    return records


def margin_lines(records: list[dict], margins: list[float]) -> list[str]:
    """A markdown table: median / mean error per category and kind, for each margin."""
    groups = [(c, k) for c in COIL_CATEGORIES for k in ("seen", "unseen")
              if any(r["category"] == c and r["kind"] == k for r in records)]
    lines = ["| instance_margin | " + " | ".join(f"{c} {k} median / mean" for c, k in groups)
             + " | sum of medians | sum of means |", "|---|" + "---|" * (len(groups) + 2)]
    for m in margins:
        cells, medians, means = [], [], []
        for c, k in groups:
            errs = [r["refined"] if r["margin"] >= m else r["plain"] for r in records
                    if r["category"] == c and r["kind"] == k]
            medians.append(float(np.median(errs)))
            means.append(float(np.mean(errs)))
            cells.append(f"{medians[-1]:.2f} / {means[-1]:.2f}")
        lines.append(f"| {m:g} | " + " | ".join(cells)
                     + f" | {sum(medians):.2f} | {sum(means):.2f} |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path,
                        default=Path(__file__).resolve().parents[2] / "shared" / "data" / "coil-100")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                        help="one setting per --param, space-separated NAME=VALUE items "
                        "(each is a row; none: the defaults)")
    parser.add_argument("--margins", help="comma-separated RecognitionOptions.margin values to study on "
                        "seen and left-out instances (e.g. 1.0,1.1,inf)")
    parser.add_argument("--markdown", type=Path)
    args = parser.parse_args()
    settings = [{}] if not args.param else [parse_settings(p.split()) for p in args.param]
    if args.margins:
        margins = [float(m) for m in args.margins.split(",")]
        lines = ["Command: `python " + " ".join(shlex.quote(a) for a in sys.argv) + "`"]
        for params in settings:
            lines += ["", f"Setting: {params or 'defaults'}", "",
                      *margin_lines(margin_records(args.data, params), margins)]
            print("\n".join(lines[-len(margins) - 4:]), flush=True)
        if args.markdown:
            args.markdown.write_text("\n".join(lines) + "\n")
        return
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
