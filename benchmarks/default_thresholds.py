"""Each preset's default threshold (``min_score``): chosen by cross-validation so that
few empty frames report an object.

Instance presets (``cluttered``, ``turntable``): ``posevote evaluate frames``
run with the preset (the 40 development COIL objects in 640x480 and
1280x720 mosaics of EPFL cars 1-10 frames, and empty mosaics, each looked at
by every object's model; estimated without a threshold). The folds are
five groups of objects (every fifth object).

``category``: a car model finds cars in those mosaics, so its data is
``epfl-cv`` (every 4th frame, the preset's row; its five folds of cars) and
empty 640x480 and 1280x720 mosaics of scikit-image's bundled photographs
(no cars), 8 per size, looked at by each fold's model.

For each fold, the threshold is the lowest detection score (a frame's
``top_score``: the contrast where the preset measures it) that at most
``--false-alarms`` of the *other* folds' empty frames (both sizes together)
exceed; it is then applied to the fold's own frames: the share of its
objects found (score over the threshold and box IoU >= 0.5) and of its
empty frames reporting an object. The printed default is the threshold
chosen the same way on every fold. The rule aims under the issue's 5%
(``--false-alarms 0.025``) because development figures have overstated
held-out ones.

Usage::

    python benchmarks/default_thresholds.py [--data ../shared/data]
        [--presets cluttered,turntable,category] [--runs DIR] [--jobs 2]
        [--false-alarms 0.025] [--markdown FILE]

``--runs`` keeps each preset's frames run (``DIR/<preset>``) and reads it
again instead of running it when its ``records.jsonl`` is there.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from _markdown import emit  # noqa: E402

from posevote import PoseEstimator  # noqa: E402
from posevote._io import atomic_write_text, read_records  # noqa: E402
from posevote.evaluation.frames import FramesSetup, mosaic, run_frames  # noqa: E402
from posevote.evaluation.protocols import epfl_cv  # noqa: E402
from posevote.evaluation.runner import run_protocol, slug  # noqa: E402
from posevote.evaluation.synthetic import bundled_photographs  # noqa: E402
from posevote.presets import get_preset  # noqa: E402

FOLDS = 5
SIZES = ((480, 640), (720, 1280))
#: Empty frames per size and epfl-cv fold (the category preset).
EMPTY_PER_FOLD = 16


def threshold_at(empty_scores: np.ndarray, false_alarms: float) -> float:
    """The lowest threshold that at most ``false_alarms`` of ``empty_scores`` exceed."""
    s = np.sort(np.asarray(empty_scores, dtype=float))[::-1]
    allowed = int(np.floor(false_alarms * len(s)))
    return float(s[allowed]) if allowed < len(s) else 0.0


def _label(size: Any) -> str:
    return "EPFL frames" if size is None else f"{size[1]}x{size[0]}"


def shares(records: list[dict[str, Any]], threshold: float) -> dict[str, float]:
    """Found % per frame size and together, and the empty frames' false alarms %."""
    out: dict[str, float] = {}
    objects = [r for r in records if r["kind"] == "object"]
    for label in sorted({_label(r["size"]) for r in objects}, key=len):
        obj = [r for r in objects if _label(r["size"]) == label]
        out[f"found {label}"] = 100.0 * float(np.mean(
            [r["score"] > threshold and r["iou"] >= 0.5 for r in obj]))
    out["found all"] = 100.0 * float(np.mean(
        [r["score"] > threshold and r["iou"] >= 0.5 for r in objects]))
    empty = [r for r in records if r["kind"] == "empty"]
    out["false alarms"] = 100.0 * float(np.mean([r["score"] > threshold for r in empty]))
    return out


def cross_validate(records: list[dict[str, Any]], false_alarms: float
                   ) -> tuple[float, list[dict[str, float]]]:
    """The threshold chosen on every object, and each fold's held-out shares."""
    objects = sorted({r["object"] for r in records})
    folds = []
    for k in range(min(FOLDS, len(objects))):
        held = set(objects[k::FOLDS])
        train = [r["score"] for r in records if r["kind"] == "empty" and r["object"] not in held]
        t = threshold_at(np.array(train), false_alarms)
        folds.append({"threshold": t, **shares([r for r in records if r["object"] in held], t)})
    everyone = threshold_at(np.array([r["score"] for r in records if r["kind"] == "empty"]),
                            false_alarms)
    return everyone, folds


def category_records(data: str, runs: Path, jobs: int, params: dict[str, Any] | None = None
                     ) -> list[dict[str, Any]]:
    """epfl-cv's cars and empty mosaics of photographs, each fold's model looking ("object" is
    the fold); epfl-cv is run in ``runs/category-epfl-cv`` unless it is there, its main row
    with ``params`` over its own."""
    protocol = epfl_cv(data)
    if params:
        protocol = replace(protocol, rows=tuple(
            replace(r, params={**(r.params or {}), **params}) if r.name == protocol.main_row
            else r for r in protocol.rows))
    out = runs / "category-epfl-cv"
    if not (out / "summary.json").exists():
        print("running epfl-cv (every 4th frame, the category row) ...", file=sys.stderr,
              flush=True)
        run_protocol(protocol, out, jobs=jobs, every=4, rows=[protocol.main_row])
    empties_path = out / "empty_frames.jsonl"
    if empties_path.exists():
        empties = [json.loads(line) for line in empties_path.read_text().splitlines()]
    else:
        photos = bundled_photographs()
        empties = []
        for fold, split in enumerate(protocol.splits, start=1):
            key = f"{slug(protocol.main_row)}__{slug(split.name)}"
            est = PoseEstimator.load(out / "models" / f"{key}.npz").set_params(
                **{**(params or {}), "min_score": 0.0})
            for shape in SIZES:
                for k in range(EMPTY_PER_FOLD):
                    rng = np.random.default_rng([fold, shape[1], k])
                    result = est.estimate(mosaic(shape, rng=rng, frames=photos))
                    best = result.best
                    empties.append({"object": fold, "kind": "empty", "size": list(shape),
                                    "index": k, "score": float(result.top_score),
                                    "probability": None if best is None else best.probability})
        atomic_write_text(empties_path, "".join(json.dumps(r) + "\n" for r in empties))
    cars = []
    for fold, split in enumerate(protocol.splits, start=1):
        key = f"{slug(protocol.main_row)}__{slug(split.name)}"
        cars += [{"object": fold, "kind": "object", "size": None, "score": r["score"],
                  "iou": r.get("iou", 0.0), "probability": r.get("probability"),
                  "error_deg": r["error_deg"], "detected": r.get("detected")}
                 for r in read_records(out / "records" / f"{key}.jsonl")]
    return cars + empties


def preset_records(preset: str, data: str, runs: Path, jobs: int,
                   params: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """The frames run of ``preset``, ``params`` over it (run now unless ``runs/<preset>``
    holds one)."""
    if preset == "category":
        return category_records(data, runs, jobs, params)
    path = runs / preset / "records.jsonl"
    if not path.exists():
        print(f"running the frames benchmark with {preset} ...", file=sys.stderr, flush=True)
        run_frames(FramesSetup(preset=preset, params=params or {}), data, runs / preset,
                   jobs=jobs)
    return [json.loads(line) for line in path.read_text().splitlines()]


def report(results: dict[str, tuple[float, list[dict[str, float]]]], false_alarms: float) -> str:
    """The chosen thresholds and their held-out folds, as Markdown."""
    lines = [f"Threshold: the lowest detection score (`cluttered`: the contrast; the others: "
             f"the score) that at most {100 * false_alarms:g}% of the "
             "other folds' empty frames exceed (both sizes together); found: score over "
             "it and box IoU >= 0.5. Held-out figures per fold (instance presets: 8 "
             "objects, 32 object frames and 16 empty frames; category: 2 cars of epfl-cv "
             f"and {2 * EMPTY_PER_FOLD} empty frames).\n"]
    for preset, (chosen, folds) in results.items():
        keys = tuple(folds[0])[1:]
        lines += ["", "| preset | default | fold | threshold | "
                  + " | ".join(f"{k} %" for k in keys) + " |",
                  "|---|---|---|---|" + "---|" * len(keys)]
        for i, f in enumerate(folds, 1):
            lines.append(f"| {preset} | {chosen:.4f} | {i} | {f['threshold']:.4f} | "
                         + " | ".join(f"{f[k]:.1f}" for k in keys) + " |")
        mean = {k: np.mean([f[k] for f in folds]) for k in keys}
        low = {k: min(f[k] for f in folds) for k in keys}
        high = {k: max(f[k] for f in folds) for k in keys}
        lines.append(f"| {preset} | {chosen:.4f} | mean (min-max) | – | "
                     + " | ".join(f"{mean[k]:.1f} ({low[k]:.0f}-{high[k]:.0f})" for k in keys)
                     + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared/data"))
    ap.add_argument("--presets", default="cluttered,turntable,category")
    ap.add_argument("--runs", default="results/default_thresholds",
                    help="each preset's frames run is kept (and read again) here")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--false-alarms", type=float, default=0.025)
    ap.add_argument("--markdown", help="also write the printed report here")
    args = ap.parse_args(argv)
    if not 0.0 <= args.false_alarms < 1.0:
        ap.error(f"--false-alarms must be in [0, 1), got {args.false_alarms}")
    presets = [p.strip() for p in args.presets.split(",") if p.strip()]
    for p in presets:
        get_preset(p)
    results = {p: cross_validate(preset_records(p, args.data, Path(args.runs), args.jobs),
                                 args.false_alarms) for p in presets}
    return emit(report(results, args.false_alarms), args.markdown, __file__, argv,
                fenced=False)


if __name__ == "__main__":
    sys.exit(main())
