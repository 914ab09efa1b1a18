"""Study: a learned box regression, then the pose from the appearance of the regressed box.

Reads the results folder of an epfl-cv run of the main row (its
``results.csv`` and the models it saved; how to make one is below). For
each fold, boxes jittered around the true box of the fold's training
frames (``--jitter`` of the size in position and log-size, half that in
log-aspect; 8 per frame) give the HOG descriptor of the verification
(:func:`posevote.inference.verification.box_descriptor`, the model's
window) and the offsets back to the true box; a ridge regression per
azimuth range (``--bins``, each fitted on the training frames within one
bin width of its centre, chosen at test time by the estimate's azimuth)
maps one to the other. Each test frame's final box is regressed
``--steps`` times; then the training view whose descriptor is nearest to
the regressed box's, among those within ``--window-deg`` of the estimate,
gives the azimuth. Prints the median IoU after each step and the errors.
Training frames only train; cars 11-20 are never read. This is the study
behind ``PoseEstimator(appearance_refine=True)`` (docs/TUNING.md, stop 18);
the other options are the variants it tried (``--help``). It reads the
records of a run *without* ``appearance_refine``, which the epfl-cv
protocol now uses; make one with::

    python benchmarks/tune_epfl.py --every 8 --keep /tmp/epfl-cv-8 --setting \
        "position_sigma=6.0 density_cap=0.5 max_search_features=1000 verify_candidates=40"

and pass ``--results /tmp/epfl-cv-8/0``.

Usage::

    python benchmarks/epfl_box_regression.py --results /tmp/epfl-cv-8/0 [--alpha 100]
        [--bins 8] [--window-deg 45] [--steps 3] [--jitter 0.15] [--per-frame 8]
        [--context 1.0] [--k 1] [--flip-margin M] [--search F] [--mirror]
        [--jittered-views] [--skip-every N]
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np
from sklearn.linear_model import Ridge

from posevote import PoseEstimator
from posevote.data import read_image
from posevote.evaluation.protocols import epfl_cv
from posevote.geometry import box_iou
from posevote.inference.verification import (
    box_descriptor,
    box_offsets,
    jittered_boxes,
    shift_box,
)

ROW = "weights + fitting"


def grown(box: tuple[float, ...], factor: float) -> tuple[float, float, float, float]:
    """``box`` scaled by ``factor`` about its centre (the regression sees this much context)."""
    x, y, w, h = box
    return x + w * (1 - factor) / 2, y + h * (1 - factor) / 2, w * factor, h * factor


def circular_error_deg(a: float, b: float) -> float:
    """Absolute difference of two azimuths, degrees, on the full circle."""
    return abs((a - b + 180.0) % 360.0 - 180.0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", type=Path, required=True)
    parser.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared"
                                              / "data"))
    parser.add_argument("--alpha", type=float, default=100.0)
    parser.add_argument("--bins", type=int, default=8)
    parser.add_argument("--window-deg", type=float, default=45.0)
    parser.add_argument("--steps", type=int, default=3)
    parser.add_argument("--jitter", type=float, default=0.15)
    parser.add_argument("--context", type=float, default=1.0,
                        help="the regression reads the box grown by this factor")
    parser.add_argument("--k", type=int, default=1,
                        help="the azimuth is the circular mean of this many nearest views")
    parser.add_argument("--flip-margin", type=float, default=None,
                        help="also look within the window around the estimate's half-turn, and "
                             "take it when its nearest view is nearer by this fraction")
    parser.add_argument("--search", type=float, default=0.0,
                        help="also describe the regressed box moved by +-this fraction (27 boxes) "
                             "and take the nearest view over all of them")
    parser.add_argument("--mirror", action="store_true",
                        help="add the training frames mirrored left-right, at azimuth -a")
    parser.add_argument("--jittered-views", action="store_true",
                        help="the nearest view among the jittered training boxes' descriptors too")
    parser.add_argument("--skip-every", type=int, default=0,
                        help="leave out the test frames of every N-th (a second selection)")
    parser.add_argument("--per-frame", type=int, default=8, help="jittered boxes per training frame")
    args = parser.parse_args(argv)
    with open(args.results / "results.csv", newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["row"] == ROW]
    rng = np.random.default_rng(0)
    width = 360.0 / args.bins
    ious, errors, before = [], [], []
    for split in epfl_cv(args.data).splits:
        index = {Path(im).name: i for i, im in enumerate(split.test.images)}
        test_rows = [r for r in rows if r["split"] == split.name and not (
            args.skip_every and index[Path(r["image"]).name] % args.skip_every == 0)]
        if not test_rows:
            continue
        key = split.name.replace("_to_", "-to-")
        est = PoseEstimator.load(args.results / "models" / f"weights-fitting__{key}.npz")
        window, views = est.descriptor_window_, est.view_descriptors_
        view_az = np.degrees(est.full_model_.view_azimuth) % 360.0
        x, y, az = [], [], []
        samples = []
        for image, truth, pose in zip(split.train.images, split.train.boxes, split.train.poses,
                                      strict=True):
            img = read_image(image)
            samples.append((img, tuple(truth), float(pose[0])))
            if args.mirror:
                bx, by, bw, bh = truth
                flipped = np.ascontiguousarray(img[:, ::-1])
                fbox = (img.shape[1] - bx - bw, by, bw, bh)
                samples.append((flipped, fbox, -float(pose[0])))
                d = box_descriptor(flipped, fbox, window)
                if d is not None:
                    views = np.vstack([views, d[None]])
                    view_az = np.append(view_az, np.degrees(-pose[0]) % 360.0)
        for img, truth, a in samples:
            for box in jittered_boxes(truth, rng, n=args.per_frame, jitter=args.jitter):
                d = box_descriptor(img, grown(box, args.context), window)
                if d is not None:
                    x.append(d)
                    y.append(box_offsets(box, truth))
                    az.append(np.degrees(a) % 360.0)
        x_arr, y_arr, az_arr = np.array(x), np.array(y), np.array(az)
        if args.jittered_views:
            views = np.vstack([views, x_arr])
            view_az = np.concatenate([view_az, az_arr])
        regressions = []
        for k in range(args.bins):
            near = np.array([circular_error_deg(a, (k + 0.5) * width) <= width for a in az_arr])
            regressions.append(Ridge(alpha=args.alpha).fit(x_arr[near], y_arr[near]))
        for r in test_rows:
            img = read_image(r["image"])
            box = tuple(float(r[k]) for k in ("box_x", "box_y", "box_w", "box_h"))
            truth = tuple(float(r[k]) for k in ("truth_box_x", "truth_box_y", "truth_box_w",
                                                 "truth_box_h"))
            estimate, true_az = float(r["estimate_deg"]), float(r["truth_deg"])
            reg = regressions[int((estimate % 360.0) // width) % args.bins]
            trail = [box_iou(box, truth)]
            for _ in range(args.steps):
                d = box_descriptor(img, grown(box, args.context), window)
                if d is None:
                    break
                box = shift_box(box, reg.predict(d[None])[0])
                trail.append(box_iou(box, truth))
            ious.append(trail + [trail[-1]] * (args.steps + 1 - len(trail)))
            before.append(circular_error_deg(estimate, true_az))
            d = box_descriptor(img, box, window)
            near = np.flatnonzero([circular_error_deg(a, estimate) <= args.window_deg
                                   for a in view_az])
            if d is None or not len(near):
                errors.append(before[-1])
                continue
            dist = np.sqrt(((views[near] - d) ** 2).sum(axis=1))
            if args.search > 0:
                f = args.search
                for dx in (-f, 0.0, f):
                    for dy in (-f, 0.0, f):
                        for ds in (-f, 0.0, f):
                            other = box_descriptor(img, shift_box(box, np.array([dx, dy, ds, ds])),
                                                   window)
                            if other is not None:
                                dist = np.minimum(dist, np.sqrt(((views[near] - other) ** 2
                                                                 ).sum(axis=1)))
            nearest = near[np.argsort(dist)[:args.k]]
            if args.flip_margin is not None:
                back = np.flatnonzero([circular_error_deg(a, estimate + 180.0) <= args.window_deg
                                       for a in view_az])
                back_dist = np.sqrt(((views[back] - d) ** 2).sum(axis=1))
                if len(back) and back_dist.min() < (1.0 - args.flip_margin) * dist.min():
                    nearest = back[np.argsort(back_dist)[:args.k]]
            mean = np.degrees(np.angle(np.exp(1j * np.radians(view_az[nearest])).mean()))
            errors.append(circular_error_deg(float(mean), true_az))
    iou_arr = np.array(ious)
    print("median IoU after each step:", " ".join(f"{v:.3f}" for v in np.median(iou_arr, axis=0)),
          " found (IoU >= 0.5):", " ".join(f"{v:.1%}" for v in (iou_arr >= 0.5).mean(axis=0)))
    found = iou_arr[:, -1] >= 0.5
    for name, e in (("estimate", np.array(before)), ("regressed box, nearest view", np.array(errors))):
        print(f"{name:28s} n {len(e)}  median {np.median(e):.2f}  mean {e.mean():.2f}  "
              f"< 45: {100 * np.mean(e < 45):.1f}%  (boxes found: median {np.median(e[found]):.2f}, "
              f"< 45 {100 * np.mean(e[found] < 45):.1f}%; missed: < 45 {100 * np.mean(e[~found] < 45):.1f}%)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
