"""Calibration of the mode probabilities on development records (issue 26).

Reads the records of ``posevote evaluate`` results folders (each record
holds the score profile over viewpoints, the best and second modes and the
error) and, for each sharpness ``k`` of :mod:`posevote.refinement.probability`,
recomputes every test image's best-mode probability and scores it against
"the best mode is within 30 degrees of the truth": log-loss, Brier score and
expected calibration error (ECE, 10 bins). The folds of the folders (their
splits) cross-validate the choice: ``k`` is chosen on all folds but one and
scored on that one. It prints the table, the chosen ``k`` (the lowest pooled
log-loss) and writes a reliability plot.

Usage::

    python benchmarks/calibrate_modes.py RESULTS_DIR [RESULTS_DIR ...] [--row NAME ...]
        [--plot docs/results/mode_calibration.png] [--markdown docs/results/mode_calibration.md]
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
from pathlib import Path

import numpy as np

from posevote._io import atomic_write_text, atomic_write_with, read_records
from posevote.geometry import viewing_direction
from posevote.refinement.probability import MODE_RADIUS, MODE_SHARPNESS, mode_probabilities

SHARPNESS = (1.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 16.0, 20.0, 25.0, 30.0, 40.0, 60.0)


def load(folders: list[Path], rows: list[str] | None) -> list[dict]:
    """The records with a profile, tagged with their folder's name."""
    out = []
    for folder in folders:
        for path in sorted((folder / "records").glob("*.jsonl")):
            for rec in read_records(path):
                if rec.get("profile") and rec.get("estimate_deg") is not None and (
                        rows is None or rec["row"] in rows):
                    out.append({**rec, "folder": folder.name})
    if not out:
        raise SystemExit("no records with a score profile in " + ", ".join(map(str, folders)))
    return out


def best_probability(rec: dict, k: float) -> float:
    prof = np.array(rec["profile"], dtype=float)
    d = viewing_direction(np.radians(prof[:, 0]), np.radians(prof[:, 1]))
    modes = [rec["estimate_deg"]] + ([rec["second_deg"]] if rec.get("second_deg") is not None
                                     else [])
    m = viewing_direction(np.radians(modes), np.zeros(len(modes)))
    return float(mode_probabilities(d, prof[:, 2], m, sharpness=k)[0])


def scores(p: np.ndarray, y: np.ndarray) -> dict[str, float]:
    q = np.clip(p, 1e-4, 1 - 1e-4)
    bins = np.minimum((p * 10).astype(int), 9)
    ece = sum(abs(p[bins == b].mean() - y[bins == b].mean()) * np.mean(bins == b)
              for b in range(10) if np.any(bins == b))
    return {"log_loss": float(-np.mean(y * np.log(q) + (1 - y) * np.log(1 - q))),
            "brier": float(np.mean((p - y) ** 2)), "ece": float(ece),
            "mean_p": float(p.mean()), "right": float(y.mean())}


def plot(p: np.ndarray, y: np.ndarray, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    edges = np.linspace(0, 1, 11)
    bins = np.minimum((p * 10).astype(int), 9)
    fig, (ax, hx) = plt.subplots(2, 1, figsize=(4.2, 5.2), height_ratios=(3, 1), sharex=True)
    centres = [(edges[b] + edges[b + 1]) / 2 for b in range(10) if np.any(bins == b)]
    ax.plot([0, 1], [0, 1], color="0.6", lw=0.8, label="perfect calibration")
    ax.plot([p[bins == b].mean() for b in range(10) if np.any(bins == b)],
            [y[bins == b].mean() for b in range(10) if np.any(bins == b)], "o-",
            color="tab:blue", label="best mode")
    ax.set_ylabel("share right (error < 30°)")
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=9)
    hx.bar(centres, [np.sum(bins == b) for b in range(10) if np.any(bins == b)], width=0.09,
           color="0.4")
    hx.set_xlabel("predicted probability of the best mode")
    hx.set_ylabel("images")
    atomic_write_with(path, lambda tmp: fig.savefig(tmp, dpi=100, bbox_inches="tight"))
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="+", type=Path)
    ap.add_argument("--row", action="append", default=None, help="only this row (repeatable)")
    ap.add_argument("--plot", type=Path, default=None)
    ap.add_argument("--markdown", type=Path, default=None)
    args = ap.parse_args(argv)
    recs = load(args.folders, args.row)
    y = np.array([r["error_deg"] < math.degrees(MODE_RADIUS) for r in recs], dtype=float)
    folds = np.array([f"{r['folder']}/{r['split']}" for r in recs])
    table = {k: np.array([best_probability(r, k) for r in recs]) for k in SHARPNESS}
    lines = [f"{len(recs)} test images from {', '.join(sorted({r['folder'] for r in recs}))}; "
             f"rows: {', '.join(sorted({r['row'] for r in recs}))}",
             "| k | log-loss | Brier | ECE | mean p | share right |", "|---|---|---|---|---|---|"]
    for k, p in table.items():
        s = scores(p, y)
        lines.append(f"| {k:g} | {s['log_loss']:.4f} | {s['brier']:.4f} | {s['ece']:.4f} "
                     f"| {s['mean_p']:.3f} | {s['right']:.3f} |")
    best = min(SHARPNESS, key=lambda k: scores(table[k], y)["log_loss"])
    # Leave one fold out: the k chosen without it, scored on it.
    held = np.zeros(len(recs))
    chosen = []
    for f in sorted(set(folds)):
        out = folds == f
        k = min(SHARPNESS, key=lambda k: scores(table[k][~out], y[~out])["log_loss"])
        chosen.append(k)
        held[out] = table[k][out]
    s = scores(held, y)
    lines += ["", f"lowest pooled log-loss: k = {best:g} (the shipped MODE_SHARPNESS is "
                  f"{MODE_SHARPNESS:g})",
              f"leave one fold out ({len(set(folds))} folds, k chosen {min(chosen):g}-"
              f"{max(chosen):g}): log-loss {s['log_loss']:.4f}, Brier {s['brier']:.4f}, "
              f"ECE {s['ece']:.4f}; mean probability {s['mean_p']:.3f} against "
              f"{s['right']:.3f} right"]
    p = table.get(MODE_SHARPNESS, held)
    edges = np.linspace(0, 1, 11)
    bins = np.minimum((p * 10).astype(int), 9)
    lines += ["", f"reliability at k = {MODE_SHARPNESS:g}:", "| predicted | images | right |",
              "|---|---|---|"]
    for b in range(10):
        if np.any(bins == b):
            lines.append(f"| {edges[b]:.1f}-{edges[b + 1]:.1f} (mean {p[bins == b].mean():.2f}) "
                         f"| {np.sum(bins == b)} | {y[bins == b].mean():.2f} |")
    text = "\n".join(lines) + "\n"
    print(text, end="")
    if args.plot:
        plot(p, y, args.plot, f"mode probabilities, k = {MODE_SHARPNESS:g} ({len(recs)} images)")
    if args.markdown:
        command = shlex.join(["python", "benchmarks/calibrate_modes.py", *(argv or sys.argv[1:])])
        atomic_write_text(args.markdown, f"```\n$ {command}\n```\n\n{text}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
