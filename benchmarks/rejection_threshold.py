"""The rejection threshold (``min_score``): chosen by cross-validation over objects.

Data: the 40 development objects of ``../shared/data/coil-100``. Each object
gets an instance model (views at 0, 20, ..., 340 degrees). Its *right*
images are its own views between the training views (10, 30, ..., 350
degrees); its *wrong* images are four views (0, 90, 180, 270 degrees) of
each of the 39 other objects, and background crops of scikit-image's
bundled photographs. With ``--clutter`` the ``cluttered`` preset is
measured instead: right and wrong views pasted on clutter with 20%
occlusion, and clutter alone (fewer images: the cluttered search is slow).

Cross-validation: the objects are split into five folds. For each fold the
threshold that maximises the balanced accuracy (the mean of the share of
right images kept and of wrong images rejected) on the *other* folds'
models is applied to the fold's own models. The reported threshold is the
one chosen on all 40 objects; the held-out shares say what it does on
objects it was not chosen on.

Usage::

    python benchmarks/rejection_threshold.py [--data ../shared/data/coil-100]
        [--clutter] [--jobs 2] [--json FILE] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from _markdown import write_markdown  # noqa: E402

from posevote import PoseEstimator  # noqa: E402
from posevote.data import read_coil  # noqa: E402
from posevote.evaluation.synthetic import clutter_background, paste_on_clutter  # noqa: E402
from posevote.geometry import angular_error  # noqa: E402

FOLDS = 5


def objects_in(folder: str) -> list[int]:
    """The object numbers present in a COIL-100 folder."""
    found = {int(p.name[3:].split("__")[0]) for p in Path(folder).glob("obj*__*.png")}
    return sorted(found)


def run_object(obj: int, objects: list[int], data: str, clutter: bool, seed: int) -> dict:
    """Scores of one object's model on its right and wrong images."""
    rng = np.random.default_rng(seed + obj)
    train = read_coil(data, objects=[obj], azimuths_deg=range(0, 360, 20))
    right_az = range(10, 360, 20) if not clutter else range(10, 360, 60)
    right = read_coil(data, objects=[obj], azimuths_deg=right_az)
    others = [o for o in objects if o != obj]
    if clutter:
        others = [int(o) for o in rng.choice(others, size=12, replace=False)]
    wrong = read_coil(data, objects=others, azimuths_deg=(0, 90, 180, 270) if not clutter
                      else (int(rng.choice([0, 90, 180, 270])),))
    preset = "cluttered" if clutter else "default"
    est = PoseEstimator.from_preset(preset, min_score=0.0).fit(
        train.load_images(), train.poses, boxes=train.boxes)

    def scene(img: np.ndarray, box: np.ndarray) -> np.ndarray:
        return paste_on_clutter(img, box, rng=rng).image if clutter else img

    n_bg = 6 if clutter else 20
    shape = (256, 256) if clutter else (128, 128)
    backgrounds = [clutter_background(shape, rng=np.random.default_rng(seed + 1000 + k))
                   for k in range(n_bg)]
    out: dict = {"object": obj, "right": [], "right_error_deg": [], "wrong": [],
                 "background": []}
    for img, box, pose in zip(right.load_images(), right.boxes, right.poses, strict=True):
        r = est.estimate(scene(img, box))
        out["right"].append(r.best.detection_score if r.best is not None else 0.0)
        out["right_error_deg"].append(
            float(np.degrees(angular_error(r.best.azimuth, pose[0]))) if r.best else 180.0)
    for img, box in zip(wrong.load_images(), wrong.boxes, strict=True):
        r = est.estimate(scene(img, box))
        out["wrong"].append(r.best.detection_score if r.best is not None else 0.0)
    for img in backgrounds:
        r = est.estimate(img)
        out["background"].append(r.best.detection_score if r.best is not None else 0.0)
    return out


def best_threshold(right: np.ndarray, wrong: np.ndarray) -> float:
    """The threshold (midway between observed scores) of the highest balanced accuracy."""
    values = np.unique(np.concatenate([right, wrong]))
    cuts = np.concatenate([[0.0], (values[1:] + values[:-1]) / 2.0])
    kept = (right[None, :] > cuts[:, None]).mean(axis=1)
    rejected = (wrong[None, :] <= cuts[:, None]).mean(axis=1)
    return float(cuts[int(np.argmax(kept + rejected))])


def pooled(results: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    right = np.concatenate([r["right"] for r in results])
    wrong = np.concatenate([r["wrong"] + r["background"] for r in results])
    return right, wrong


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[1].parent
                                          / "shared/data/coil-100"))
    ap.add_argument("--clutter", action="store_true", help="the cluttered preset, in clutter")
    ap.add_argument("--objects", help="comma-separated objects (default: all in --data)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", help="write the per-object scores here")
    ap.add_argument("--markdown", help="also write the printed report here")
    args = ap.parse_args(argv)
    everything = objects_in(args.data)
    if len(everything) < 2:
        ap.error(f"--data {args.data}: needs the views (objN__A.png) of two objects or more")
    objects = [int(o) for o in args.objects.split(",")] if args.objects else everything
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        results = list(pool.map(run_object, objects, [everything] * len(objects),
                                [args.data] * len(objects), [args.clutter] * len(objects),
                                [args.seed] * len(objects)))
    wall = time.perf_counter() - t0
    report = io.StringIO()
    with contextlib.redirect_stdout(report):
        print_report(args, results, wall)
    print(report.getvalue(), end="")
    if args.json:
        Path(args.json).write_text(json.dumps(results))
    if args.markdown:
        write_markdown(args.markdown, __file__, argv, report.getvalue())
    return 0


def print_report(args, results: list[dict], wall: float) -> None:
    preset = "cluttered" if args.clutter else "default"
    right, wrong = pooled(results)
    print(f"rejection threshold, preset {preset}: {len(results)} object models, "
          f"{len(right)} right-object images, {len(wrong)} wrong-object or background images")
    q = [5, 25, 50, 75, 95]
    print("score percentiles " + "/".join(map(str, q)) + ":")
    print("  right      " + " ".join(f"{v:.3f}" for v in np.percentile(right, q)))
    for kind in ("wrong", "background"):
        s = np.concatenate([r[kind] for r in results])
        print(f"  {kind:<10} " + " ".join(f"{v:.3f}" for v in np.percentile(s, q)))
    order = np.random.default_rng(0).permutation(len(results))
    folds = [f for f in np.array_split(order, min(FOLDS, len(results))) if len(f)]
    kept_all, rejected_all = [], []
    print(f"{FOLDS}-fold cross-validation over objects (threshold chosen on the other folds):")
    for k, held in enumerate(folds):
        train = [results[i] for i in range(len(results)) if i not in set(held)]
        test = [results[i] for i in held]
        t = best_threshold(*pooled(train))
        r_test, w_test = pooled(test)
        kept, rejected = float(np.mean(r_test > t)), float(np.mean(w_test <= t))
        kept_all.append(kept)
        rejected_all.append(rejected)
        print(f"  fold {k + 1}: objects {sorted(results[i]['object'] for i in held)}: "
              f"threshold {t:.3f}, right kept {100 * kept:.1f}%, wrong rejected "
              f"{100 * rejected:.1f}%")
    print(f"  held-out mean: right kept {100 * np.mean(kept_all):.1f}% "
          f"(min {100 * np.min(kept_all):.1f}%), wrong rejected {100 * np.mean(rejected_all):.1f}% "
          f"(min {100 * np.min(rejected_all):.1f}%)")
    t = best_threshold(right, wrong)
    errors = np.concatenate([r["right_error_deg"] for r in results])
    scores = right
    print(f"threshold chosen on all {len(results)} objects: {t:.3f}; on them it keeps "
          f"{100 * np.mean(right > t):.1f}% of right images and rejects "
          f"{100 * np.mean(wrong <= t):.1f}% of wrong ones")
    for share in (0.95, 0.99):
        cut = float(np.quantile(right, 1.0 - share))
        print(f"  for comparison, keeping {100 * share:.0f}% of right images (threshold "
              f"{cut:.3f}) rejects {100 * np.mean(wrong <= cut):.1f}% of wrong ones")
    lost = errors[scores <= t]
    print(f"right images it rejects: {len(lost)}, of which {int(np.sum(lost > 30))} have a "
          f"pose error over 30 deg (of {int(np.sum(errors > 30))} such errors in all)")
    print(f"wall {wall:.0f} s with {args.jobs} processes")


if __name__ == "__main__":
    sys.exit(main())
