"""Each preset's probability calibration (``SearchOptions.calibration``), fitted on
development folds that hold the wrong answers.

The best mode's probability is ``sigmoid(a logit(share) + b ln(score) + c)``
of its share of the posterior over viewpoints (after the appearance step, of
its HOG front/back evidence) and its detection score (the contrast where the
preset measures it, else its score;
:func:`posevote.refinement.probability.calibrated`). For each preset, its
development estimates are made with the share itself (calibration
``(1, 0, 0)``), every estimate reported (no threshold):

- ``default``: ``coil-loio`` and ``coil-category``, their main row (unseen
  COIL objects of a category; every image);
- ``cluttered``: the frames benchmark with the preset (the 40 development
  COIL objects in 640x480 and 1280x720 mosaics of EPFL frames, and empty
  mosaics);
- ``turntable``: the frames benchmark with the preset and ``epfl-single``'s
  preset row;
- ``category``: ``epfl-cv`` (every 4th frame, the preset's row) and the
  empty mosaics of photographs of ``benchmarks/default_thresholds.py``.

An estimate is right when its best mode is within 30 degrees of the truth and
its box is found (IoU >= 0.5) where the box is known; an estimate on an empty
frame is wrong. ``(a, b, c)`` is the logistic regression of "right" on
``logit(share)`` and ``ln(score)``, over the estimates the preset reports (its
detection score over its ``min_score``, false alarms included) or over every
estimate, whichever calibrates the reported ones better held out: fitted on the
reported ones, the probability is that of a found estimate, and below the
threshold (a lowered ``min_score``) it overstates (the 'every estimate' rows).
Five folds (the protocols' splits, the
frames' objects in five groups, taken in turn) cross-validate it: each fold's
probabilities come from the fit on the other four. Reported per preset,
before (the share) and after (held out): the expected calibration error, the
share right of the estimates with p >= 0.9, of the most confident 85%, and the
log-loss, on every estimate and at the preset's threshold (an estimate below it
reports p 0). The coefficients to ship are fitted on every fold.

Usage::

    python benchmarks/calibrate_probability.py [--data ../shared/data] [--runs DIR]
        [--presets default,cluttered,turntable,category] [--jobs 2]
        [--plots DIR] [--markdown FILE]

``--runs`` (default ``results/calibration``) keeps every run and reads it again
when it is there: ``coil-loio``, ``coil-category``, ``epfl-single``,
``cluttered``, ``turntable``, ``category-epfl-cv``.
"""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from _markdown import emit  # noqa: E402
from default_thresholds import preset_records  # noqa: E402
from scipy.optimize import minimize  # noqa: E402

from posevote._io import read_records  # noqa: E402
from posevote.evaluation.metrics import accuracy_at_coverage, calibration  # noqa: E402
from posevote.evaluation.protocols import load_protocol  # noqa: E402
from posevote.evaluation.report import plot_calibration  # noqa: E402
from posevote.evaluation.runner import run_protocol, slug  # noqa: E402
from posevote.presets import get_preset  # noqa: E402
from posevote.refinement.probability import IDENTITY, MODE_RADIUS  # noqa: E402

FOLDS = 5
#: The estimates are made with the share itself.
RAW = {"search__calibration": IDENTITY}
#: The rows of the protocols the default preset is calibrated on (coil-loio's two rows).
_COIL_ROWS = ("weights + pruning + fitting", "refined with instance model + instance search")
#: Each preset's protocols and rows (empty: the main row), besides its frames runs.
PROTOCOLS: dict[str, tuple[tuple[str, tuple[str, ...]], ...]] = {
    "default": (("coil-loio", _COIL_ROWS), ("coil-category", _COIL_ROWS)),
    "turntable": (("epfl-single", ()),)}
#: Each preset's frames runs (``benchmarks/default_thresholds.py``).
FRAMES = ("cluttered", "turntable", "category")
RADIUS_DEG = float(np.degrees(MODE_RADIUS))
_TINY = 1e-6


def protocol_rows(name: str, rows: tuple[str, ...], data: str, runs: Path, jobs: int
                  ) -> list[dict[str, Any]]:
    """The records of protocol ``name``'s ``rows`` (its main row when empty; run in
    ``runs/name`` unless there), each with its fold."""
    protocol = load_protocol(name, data)
    names = rows or (protocol.main_row,)
    out = runs / name
    if not (out / "summary.json").exists():
        print(f"running {name} ...", file=sys.stderr, flush=True)
        raw = tuple(replace(r, params={**(r.params or {}), **RAW}) for r in protocol.rows)
        run_protocol(replace(protocol, rows=raw), out, jobs=jobs, rows=list(names))
    splits = [s.name for s in protocol.splits]
    records = []
    for row in names:
        for i, split in enumerate(splits):
            path = out / "records" / f"{slug(row)}__{slug(split)}.jsonl"
            for k, r in enumerate(read_records(path)):
                fold = i % FOLDS if len(splits) >= FOLDS else k % FOLDS
                boxed = r.get("detected") is not False
                records.append({"source": name, "fold": fold,
                                "share": r.get("probability") or 0.0, "score": r["score"],
                                "detection": r["score"],
                                "right": boxed and r["error_deg"] < RADIUS_DEG})
    return records


def frames_rows(preset: str, data: str, runs: Path, jobs: int) -> list[dict[str, Any]]:
    """The preset's frames run (the category's: epfl-cv and empty mosaics), each record with
    its fold."""
    out = []
    for r in preset_records(preset, data, runs, jobs, RAW):
        # A frame's box is always known; an epfl-cv record says whether it was found.
        found = r.get("detected") is not False and r.get("iou", 0.0) >= 0.5
        right = r["kind"] == "object" and found and r["error_deg"] < RADIUS_DEG
        source = "epfl-cv" if r.get("size") is None and r["kind"] == "object" else \
            f"frames, {r['kind']}"
        # A frames record's score is what the threshold reads (the contrast, where the
        # preset measures it: the frame's best); the probability reads the best mode's own.
        out.append({"source": source, "fold": r["object"] % FOLDS,
                    "share": r.get("probability") or 0.0,
                    "score": r.get("detection", r.get("pose_score", r["score"])),
                    "detection": r["score"],
                    "right": bool(right)})
    return out


def features(share: np.ndarray, score: np.ndarray) -> np.ndarray:
    """``logit(share)``, ``ln(score)``: the calibration's inputs."""
    q = np.clip(share, _TINY, 1.0 - _TINY)
    return np.c_[np.log(q / (1.0 - q)), np.log(np.maximum(score, _TINY))]


def fit(share: np.ndarray, score: np.ndarray, right: np.ndarray) -> tuple[float, float, float]:
    """``(a, b, c)`` of the logistic regression of ``right``, ``a >= 0`` (a larger share never
    lowers the probability)."""
    x = features(share, score)
    y = right.astype(float)

    def loss(w: np.ndarray) -> tuple[float, np.ndarray]:
        z = x @ w[:2] + w[2]
        p = 1.0 / (1.0 + np.exp(-z))
        err = p - y
        return (float(np.mean(np.logaddexp(0.0, z) - y * z)),
                np.r_[x.T @ err, err.sum()] / len(y))

    bounds = [(0.0, 100.0), (-100.0, 100.0), (-100.0, 100.0)]
    res = minimize(loss, np.array([1.0, 0.0, 0.0]), jac=True, method="L-BFGS-B",
                   bounds=bounds)
    a, b, c = (float(v) for v in res.x)
    return a, b, c


def apply(share: np.ndarray, score: np.ndarray, abc: tuple[float, float, float]) -> np.ndarray:
    """The calibrated probabilities (as :func:`posevote.refinement.probability.calibrated`)."""
    a, b, c = abc
    z = features(share, score) @ np.array([a, b]) + c
    return 1.0 / (1.0 + np.exp(-z))


def held_out(records: list[dict[str, Any]], reported: np.ndarray) -> np.ndarray:
    """Each record's probability from the fit on the other folds' ``reported`` records."""
    share, score, right, fold = (np.array([r[k] for r in records], dtype=float if k != "right"
                                          else bool) for k in ("share", "score", "right", "fold"))
    p = np.zeros(len(records))
    for f in range(FOLDS):
        test = fold == f
        train = ~test & reported
        if not test.any():
            continue
        if right[train].all() or not right[train].any():
            p[test] = float(right[train].mean())
            continue
        p[test] = apply(share[test], score[test], fit(share[train], score[train], right[train]))
    return p


def measures(p: np.ndarray, right: np.ndarray) -> dict[str, float]:
    """ECE, % right of p >= 0.9 (and how many), % right of the most confident 85%, log-loss."""
    hi = p >= 0.9
    q = np.clip(p, _TINY, 1.0 - _TINY)
    return {"ece": calibration(p, right)["ece"],
            "n_high": int(hi.sum()),
            "right_high": 100.0 * float(right[hi].mean()) if hi.any() else float("nan"),
            "top_85": 100.0 * accuracy_at_coverage(p, right, 0.85),
            "log_loss": float(-np.mean(np.where(right, np.log(q), np.log(1.0 - q))))}


def report(results: dict[str, dict[str, Any]]) -> str:
    """The table and the coefficients, as Markdown."""
    lines = ["Each preset's calibration, cross-validated over 5 folds (each fold's "
             "probabilities from the fit on the other four, as chosen below): before (the "
             "share: of the "
             "posterior over viewpoints, or after the appearance step the front/back share) "
             "-> after. 'every estimate': none rejected; 'at the threshold': below "
             "the preset's min_score an estimate reports p 0. Right: within 30 deg, box found "
             "where known; an empty frame's estimate is wrong.\n",
             "| preset | estimates | right % | where | ECE | p >= 0.9: n, % right | "
             "% right, top 85% | log-loss |", "|---|---|---|---|---|---|---|---|"]
    for preset, res in results.items():
        for where in ("every estimate", "at the threshold"):
            b, a = res[where]
            lines.append(
                f"| {preset} | {res['n']} | {res['rate']:.1f} | {where} | "
                f"{b['ece']:.3f} -> {a['ece']:.3f} | {b['n_high']}, {b['right_high']:.1f} -> "
                f"{a['n_high']}, {a['right_high']:.1f} | {b['top_85']:.1f} -> "
                f"{a['top_85']:.1f} | {b['log_loss']:.3f} -> {a['log_loss']:.3f} |")
    lines += ["", "Per source, every estimate (held out):", "",
              "| preset | source | estimates | right % | ECE | p >= 0.9: n, % right |",
              "|---|---|---|---|---|---|"]
    for preset, res in results.items():
        for source, (n, rate, b, a) in res["sources"].items():
            lines.append(f"| {preset} | {source} | {n} | {rate:.1f} | {b['ece']:.3f} -> "
                         f"{a['ece']:.3f} | {b['n_high']}, {b['right_high']:.1f} -> "
                         f"{a['n_high']}, {a['right_high']:.1f} |")
    lines += ["", "Fitted on every fold (`SearchOptions.calibration`, (a, b, c)), on the "
              "estimates the preset reports or on every estimate, whichever calibrates the "
              "reported ones better held out (their ECE at the threshold either way):", ""]
    lines += [f"- `{p}`: ({r['abc'][0]:.3f}, {r['abc'][1]:.3f}, {r['abc'][2]:.3f}), fitted on "
              f"{'the reported' if r['fitted on'] == 'reported' else 'every estimate'} "
              f"(reported {r['ece at the threshold']['reported']:.3f}, every "
              f"{r['ece at the threshold']['every']:.3f})" for p, r in results.items()]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared/data"))
    ap.add_argument("--presets", default="default,cluttered,turntable,category")
    ap.add_argument("--runs", default="results/calibration")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--plots", help="write each preset's held-out reliability plot here")
    ap.add_argument("--markdown", help="also write the printed report here")
    args = ap.parse_args(argv)
    runs = Path(args.runs)
    results: dict[str, dict[str, Any]] = {}
    for preset in (p.strip() for p in args.presets.split(",") if p.strip()):
        threshold = float(get_preset(preset).params.get("min_score", 0.0))
        records = [r for name, rows in PROTOCOLS.get(preset, ())
                   for r in protocol_rows(name, rows, args.data, runs, args.jobs)]
        if preset in FRAMES:
            records += frames_rows(preset, args.data, runs, args.jobs)
        share, score = (np.array([r[k] for r in records]) for k in ("share", "score"))
        right = np.array([r["right"] for r in records], dtype=bool)
        kept = np.array([r["detection"] for r in records]) > threshold
        # Fitted on the reported estimates or on every one: whichever calibrates the
        # reported ones better held out.
        masks = {"reported": kept, "every": np.ones(len(records), dtype=bool)}
        fits = {name: held_out(records, on) for name, on in masks.items()}
        ece = {name: measures(np.where(kept, p, 0.0), right & kept)["ece"]
               for name, p in fits.items()}
        chosen = min(ece, key=lambda name: ece[name])
        on, after = masks[chosen], fits[chosen]
        results[preset] = {
            "fitted on": chosen, "ece at the threshold": ece,
            "n": len(records), "rate": 100.0 * float(right.mean()),
            "every estimate": (measures(share, right), measures(after, right)),
            "at the threshold": (measures(np.where(kept, share, 0.0), right & kept),
                                 measures(np.where(kept, after, 0.0), right & kept)),
            "abc": fit(share[on], score[on], right[on]), "sources": {}}
        source = np.array([r["source"] for r in records])
        for name in dict.fromkeys(source):
            mine = source == name
            results[preset]["sources"][name] = (
                int(mine.sum()), 100.0 * float(right[mine].mean()),
                measures(share[mine], right[mine]), measures(after[mine], right[mine]))
        if args.plots:
            Path(args.plots).mkdir(parents=True, exist_ok=True)
            plot_calibration(after, right, Path(args.plots) / f"calibration_{preset}.png",
                             title=f"{preset}: held-out calibrated probability, every estimate")
    text = report(results)
    if args.plots:
        base = Path(args.markdown).parent if args.markdown else Path(".")
        where = Path(os.path.relpath(args.plots, base)).as_posix()
        text += "\nThe held-out probabilities' reliability and risk-coverage, every estimate:\n\n"
        text += "".join(f"![{p}]({where}/calibration_{p}.png)\n" for p in results)
    return emit(text, args.markdown, __file__, argv, fenced=False)


if __name__ == "__main__":
    sys.exit(main())
