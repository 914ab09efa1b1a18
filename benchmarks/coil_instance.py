"""COIL-100 instance-level benchmark (issue 2): one model per object.

Protocol: each of the 16 objects in ``../shared/data/coil-100`` is its own
instance model, trained on the views at 0, 20, ..., 340 degrees and tested
on its other 54 views; boxes and flat bottles are scored on the half circle.

``--cv`` runs the cross-validation used to choose defaults instead, on the
protocol's 18 *training* views only (never its test views): 3 folds, fold
``r`` holds out the views whose index is ``r`` modulo 3 and trains on the 12
others. A held-out view is 20 degrees from its training neighbours, and its
half-turn twin is held out too (a 40-degree-spaced split would put every
test view's half-turn twin in training, which makes half-turn symmetric
objects trivially right and cars trivially wrong).

``--selftest --clutter`` is the development set for the search in clutter:
the model is trained on the 18 training views and tested on those same views
pasted on clutter. It says nothing about precision between training views;
it measures what clutter and occlusion do to the search (gross pose errors,
position), with the held-out test views untouched.

``--clutter`` pastes each test view at a random position, scale 0.7-1.3 and
in-plane rotation +-30 degrees onto a cluttered background (scikit-image
sample images), with 20% of the object occluded, and also scores the
estimated image position. Without it, the position is scored against each
test view's box centre and the scale against 1 (the training distance), in
lines after the table.

Usage::

    python benchmarks/coil_instance.py [--data ../shared/data/coil-100]
        [--cv | --selftest] [--clutter] [--objects 1,6,...] [--param NAME=VALUE ...] [--jobs 2]
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
from dataclasses import replace
from pathlib import Path

import numpy as np

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from _markdown import write_markdown  # noqa: E402
from _settings import parse_settings  # noqa: E402

from posevote import PoseEstimator  # noqa: E402
from posevote.data import read_coil  # noqa: E402
from posevote.evaluation.metrics import summarize_errors  # noqa: E402
from posevote.evaluation.synthetic import paste_on_clutter  # noqa: E402
from posevote.geometry import angular_error, box_centre  # noqa: E402
from posevote.results import LOOKALIKE  # noqa: E402

OBJECTS = (1, 6, 8, 13, 15, 22, 23, 31, 33, 46, 54, 64, 76, 79, 91, 96)
#: The 24 objects added for cross-validation (../shared/data/coil-100/README).
MORE_OBJECTS = (7, 24, 25, 26, 41, 47, 50, 55, 56, 57, 58, 60, 61, 68, 71, 72, 73, 74, 83, 85, 86,
                92, 97, 100)
HALF_TURN = {1, 31, 46, 54, 79, 96, 13, 22, 33, 64}  # boxes and flat bottles
_ONE = {"search__viewpoint_subdivisions": 1}
_MORPH = {"morph_views": True, "search__viewpoint_subdivisions": 2}
# Each row: weights, fitting, the local refinement, and what else it sets.
ROWS = {
    "no weights": (False, False, False, _ONE),
    "weights": (True, False, False, _ONE),
    "weights + fitting": (True, True, False, _ONE),
    "+ local refinement": (True, True, True, _ONE),
    # Beyond the paper, not run by default: features morphed between views,
    # two probes per gap (posevote.model.morph; docs/history/TUNING.md, "Morphing between training views").
    "weights + fitting + morphing": (True, True, False, _MORPH),
    "+ local refinement + morphing": (True, True, True, _MORPH),
}
DEFAULT_ROWS = ("no weights", "weights", "weights + fitting", "+ local refinement")
# Settings that act when the model is fitted: a row that sets them gets a model of its own.
FIT_SETTINGS = ("morph_views",)


def row_params(row: str, preset: str) -> dict:
    """The row's settings over ``preset``: without fitting the modes are the best probes
    and the rescale step is off; the local refinement fits the profile (polishes without
    fitting); with the templates, the half-turn check and the share-scale step go with
    the local refinement."""
    weights, fit, local, extra = ROWS[row]
    base = PoseEstimator.from_preset(preset)
    templated = base.templates is not None
    params = {"weights": weights, "refine": replace(
        base.refine, fit=fit, rescale=fit and not local,
        local=("profile" if fit else "polish") if local else None,
        share_scale=templated and local), **extra}
    if base.templates is not None:
        params["templates"] = replace(base.templates, half_turn=local)
    return params
# Clean views start from the ``default`` preset, pasted views from ``cluttered``.


def splits(kind: str) -> list[tuple[list[int], list[int]]]:
    """(train azimuths, test azimuths) in degrees: ``kind`` is "protocol", "cv" or "self"."""
    if kind == "self":
        return [(list(range(0, 360, 20)), list(range(0, 360, 20)))]
    if kind == "protocol":
        return [(list(range(0, 360, 20)), [a for a in range(0, 360, 5) if a % 20])]
    views = list(range(0, 360, 20))
    return [([a for i, a in enumerate(views) if i % 3 != r], views[r::3]) for r in range(3)]


def run_object(obj: int, data: str, kind: str, clutter: bool, params: dict, seed: int,
               rows: list[str]) -> dict:
    parts = [run_split(obj, data, train_az, test_az, clutter, params, seed, rows)
             for train_az, test_az in splits(kind)]
    out = dict(parts[0])
    out["train_s"] = float(np.mean([p["train_s"] for p in parts]))
    for row in rows:
        out[row] = {k: sum((p[row][k] for p in parts), []) for k in parts[0][row]}
    return out


def run_split(obj: int, data: str, train_az: list[int], test_az: list[int], clutter: bool,
              params: dict, seed: int, rows: list[str]) -> dict:
    train = read_coil(data, objects=[obj], azimuths_deg=train_az)
    test = read_coil(data, objects=[obj], azimuths_deg=test_az)
    period = np.pi if obj in HALF_TURN else 2 * np.pi
    train_images = train.load_images()
    images = test.load_images()
    # Clean views lie where they were photographed, at the training distance.
    truth_pos = np.array([box_centre(b) for b in test.boxes])
    truth_scale = np.ones(len(images))
    if clutter:
        rng = np.random.default_rng(seed + obj)
        pasted = [paste_on_clutter(img, box, rng=rng) for img, box in zip(images, test.boxes,
                                                                          strict=True)]
        images = [p.image for p in pasted]
        truth_pos = np.array([p.position for p in pasted])
        truth_scale = np.array([p.scale for p in pasted])
    models: dict[tuple, PoseEstimator] = {}
    train_s: list[float] = []
    preset = "cluttered" if clutter else "default"

    def model_for(row: str) -> PoseEstimator:
        """The row's fitted estimator (one per distinct training-time setting)."""
        fit = {k: v for k, v in row_params(row, preset).items()
               if k in FIT_SETTINGS and k not in params}
        key = tuple(sorted(fit.items()))
        if key not in models:
            t0 = time.perf_counter()
            # The object is in every test image: nothing is rejected (min_score 0).
            models[key] = PoseEstimator.from_preset(preset, **{"min_score": 0.0, **params,
                                                               **fit}).fit(
                train_images, train.poses, boxes=train.boxes)
            train_s.append(time.perf_counter() - t0)
            models[key].estimate(images[0])  # compile once before timing
        return models[key]

    out: dict = {"object": obj}
    for row in rows:
        est = model_for(row)
        est.set_params(**{k: v for k, v in row_params(row, preset).items()
                          if k not in params and k not in FIT_SETTINGS})
        # A --param field of a group the row sets (refine.keypoints=True) wins over the row's.
        est.set_params(**{k: v for k, v in params.items() if "__" in k})
        errs, secs, pos_err, scale_err, inplane_err, prob, amb = [], [], [], [], [], [], []
        for k, (img, pose) in enumerate(zip(images, test.poses, strict=True)):
            r = est.estimate(img)
            secs.append(r.seconds)
            prob.append(0.0 if r.best is None else r.best.probability)
            amb.append(r.ambiguous)
            if r.best is None:
                errs.append(np.pi / 2 if period == np.pi else np.pi)
                pos_err.append(np.inf)
                scale_err.append(np.inf)
                inplane_err.append(np.inf)
                continue
            errs.append(float(angular_error(r.best.azimuth, pose[0], period=period)))
            pos_err.append(float(np.hypot(*(np.array(r.best.position) - truth_pos[k]))))
            scale_err.append(float(np.log(r.best.scale / truth_scale[k])))
            if clutter:
                inplane_err.append(float(np.degrees(angular_error(r.best.inplane,
                                                                  pasted[k].inplane))))
        out[row] = {"errors_deg": np.degrees(errs).tolist(), "seconds": secs,
                    "position_error_px": pos_err, "probability": prob,
                    "ambiguous": amb,
                    "log_scale_error": scale_err}
        if clutter:
            out[row]["inplane_error_deg"] = inplane_err
    first = next(iter(models.values()))
    out.update(train_s=train_s[0], n_features=first.model_.n_features,
               lookalike=float(np.median(first.model_.view_lookalike)))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[1].parent
                                          / "shared/data/coil-100"))
    split = ap.add_mutually_exclusive_group()
    split.add_argument("--cv", action="store_true", help="cross-validation on training views")
    split.add_argument("--selftest", action="store_true",
                       help="test on the training views themselves (with --clutter)")
    ap.add_argument("--clutter", action="store_true", help="cluttered, occluded test images")
    ap.add_argument("--objects", default=",".join(map(str, OBJECTS)),
                    help="comma-separated objects, or 'all' (the 40 development objects)")
    ap.add_argument("--param", action="append", default=[], help="NAME=VALUE estimator setting")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rows", default=",".join(DEFAULT_ROWS),
                    help="comma-separated ablation rows to run (default: the first four; "
                         f"all: {', '.join(ROWS)})")
    ap.add_argument("--json", help="write per-object results here")
    ap.add_argument("--markdown", help="also write the printed report here, as a markdown file")
    args = ap.parse_args(argv)
    if args.selftest and not args.clutter:
        ap.error("--selftest needs --clutter (on plain views it is trivially right)")
    params = parse_settings(args.param)
    objects = sorted(OBJECTS + MORE_OBJECTS) if args.objects == "all" \
        else [int(o) for o in args.objects.split(",")]
    rows = [r.strip() for r in args.rows.split(",")]
    for r in rows:
        if r not in ROWS:
            ap.error(f"unknown row {r!r}; rows: {', '.join(ROWS)}")
    t0 = time.perf_counter()
    kind = "self" if args.selftest else "cv" if args.cv else "protocol"
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        results = list(pool.map(run_object, objects, [args.data] * len(objects),
                                [kind] * len(objects), [args.clutter] * len(objects),
                                [params] * len(objects), [args.seed] * len(objects),
                                [rows] * len(objects)))
    wall = time.perf_counter() - t0
    report = io.StringIO()
    with contextlib.redirect_stdout(report):
        print_report(args, params, objects, rows, results, wall)
    print(report.getvalue(), end="")
    if args.json:
        Path(args.json).write_text(json.dumps(results))
    if args.markdown:
        write_markdown(args.markdown, __file__, argv, report.getvalue())
    return 0


def print_report(args, params, objects, rows, results, wall) -> None:
    protocol = ("3-fold CV on the training views 0:20:340" if args.cv
                else "self-test on the training views 0:20:340" if args.selftest
                else "train 0:20:340, test other 54")
    print(f"COIL-100 instance models, {len(objects)} objects, {protocol}"
          f"{', cluttered + 20% occluded' if args.clutter else ''}; preset "
          f"{'cluttered' if args.clutter else 'default'}, overrides {params or 'none'}")
    width = max(20, *(len(r) + 1 for r in rows))
    print(f"{'row':<{width}}{'median':>8}{'mean':>8}{'p90':>8}{'<5deg':>8}{'ms/img':>8}"
          + ("{:>10}{:>9}".format("pos<=5px", ">30deg") if args.clutter else ""))
    for row in rows:
        errs = np.concatenate([r[row]["errors_deg"] for r in results])
        secs = np.concatenate([r[row]["seconds"] for r in results])
        s = summarize_errors(errs)
        line = (f"{row:<{width}}{s['median']:>8.2f}{s['mean']:>8.2f}{s['p90']:>8.2f}"
                f"{100 * np.mean(errs < 5):>7.1f}%{1000 * np.median(secs):>8.1f}")
        if args.clutter:
            pos = np.concatenate([r[row]["position_error_px"] for r in results])
            line += f"{100 * np.mean(pos <= 5):>9.1f}%{100 * np.mean(errs > 30):>8.1f}%"
        print(line)
    if not args.clutter:
        # Against each test view's box centre and the training distance (scale 1).
        for row in rows:
            pos = np.concatenate([r[row]["position_error_px"] for r in results])
            log_s = np.concatenate([r[row]["log_scale_error"] for r in results])
            print(f"{row}: position error median {np.median(pos):.2f} px, "
                  f"{100 * np.mean(pos <= 2):.1f}% within 2 px; log-scale error median "
                  f"{np.median(log_s):+.4f}, mean |log s| {np.mean(np.abs(log_s)):.4f}")
    last = rows[-1]
    # Objects that look alike from every side: most of their estimates say so (ambiguous).
    ambiguous = {r["object"]: float(np.mean(r[last]["ambiguous"])) for r in results}
    undefined = [o for o, share in ambiguous.items() if share > 0.5]
    if len(undefined) == len(results):
        print(f"azimuth undefined ({last}: over half of an object's estimates ambiguous): "
              "every object")
    elif undefined:
        rest = np.concatenate([r[last]["errors_deg"] for r in results
                               if r["object"] not in undefined])
        print(f"azimuth undefined ({last}: over half of an object's estimates ambiguous): "
              f"objects {', '.join(map(str, undefined))}; the other "
              f"{len(results) - len(undefined)} objects: median {np.median(rest):.2f}, mean "
              f"{np.mean(rest):.2f}")
    flagged = np.concatenate([r[last]["ambiguous"] for r in results]).astype(bool)
    errors = np.concatenate([r[last]["errors_deg"] for r in results])
    if flagged.any() and not flagged.all():
        print(f"ambiguous estimates ({last}): {flagged.sum()} of {len(flagged)}, "
              f"{100 * np.mean(errors[flagged] < 30):.1f}% within 30 deg (mean "
              f"{np.mean(errors[flagged]):.2f}); the others {100 * np.mean(errors[~flagged] < 30):.1f}% "
              f"(mean {np.mean(errors[~flagged]):.2f})")
    print(f"share of ambiguous estimates per object ({last}): " + ", ".join(
        f"{o}: {100 * share:.0f}%" for o, share in ambiguous.items()))
    print("how alike each object's views are to its other sides (results.LOOKALIKE "
          f"{LOOKALIKE:g}), median over its views: " + ", ".join(
              f"{r['object']}: {r['lookalike']:.2f}" for r in results))
    print(f"per object ({last}), median/mean: " + ", ".join(
        f"{r['object']}: {np.median(r[last]['errors_deg']):.1f}/"
        f"{np.mean(r[last]['errors_deg']):.1f}" for r in results))
    print(f"training time per object: median {np.median([r['train_s'] for r in results]):.2f} s; "
          f"features per model: median {np.median([r['n_features'] for r in results]):.0f}; "
          f"wall {wall:.0f} s with {args.jobs} processes, one core each")


if __name__ == "__main__":
    sys.exit(main())
