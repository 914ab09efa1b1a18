"""Calibration of the mode probabilities on development records (issue 26).

Reads the records of ``posevote evaluate`` results folders (each record
holds the score profile over viewpoints, the best and second modes and the
error) and, for each sharpness ``k`` of :mod:`posevote.refinement.probability`,
recomputes every test image's raw best-mode probability and scores it against
"the best mode is within 30 degrees of the truth" (on the full circle, for
half-turn symmetric objects too: their twin is another mode): log-loss, Brier score and
expected calibration error (ECE, 10 bins). Then a Platt scaling of the raw
probability at the best ``k`` (``sigmoid(a logit(p) + b)``) is fitted. The
folds of the folders (their splits) cross-validate both choices: each is
made on all folds but one and scored on that one. It prints the tables, the
constants to ship, and the reliability of the shipped constants, and writes
the reliability plot.

Usage::

    python benchmarks/calibrate_modes.py RESULTS_DIR [RESULTS_DIR ...] [--row NAME ...]
        [--plot docs/results/mode_calibration.png] [--markdown docs/results/mode_calibration.md]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from _markdown import write_markdown  # noqa: E402

from posevote._io import atomic_write_with, read_records
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


def fit_platt(p: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Slope and offset of ``sigmoid(a logit(p) + b)`` by logistic regression."""
    from sklearn.linear_model import LogisticRegression

    q = np.clip(p, 1e-4, 1 - 1e-4)
    reg = LogisticRegression(C=1e6).fit(np.log(q / (1 - q))[:, None], y)
    return float(reg.coef_[0, 0]), float(reg.intercept_[0])


def calibrate(raw: np.ndarray, slope: float, offset: float) -> np.ndarray:
    q = np.clip(raw, 1e-6, 1 - 1e-6)
    return 1.0 / (1.0 + np.exp(-(slope * np.log(q / (1 - q)) + offset)))


def best_probability(rec: dict, k: float) -> float:
    prof = np.array(rec["profile"], dtype=float)
    d = viewing_direction(np.radians(prof[:, 0]), np.radians(prof[:, 1]))
    modes = [rec["estimate_deg"]] + ([rec["second_deg"]] if rec.get("second_deg") is not None
                                     else [])
    m = viewing_direction(np.radians(modes), np.zeros(len(modes)))
    return float(mode_probabilities(d, prof[:, 2], m, sharpness=k)[0])  # raw, uncalibrated


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
    # Right on the full circle: a mode's probability is that of its own viewpoint, so the
    # half-turn twin of a symmetric object counts as another mode (not as this one).
    y = np.array([abs((r["estimate_deg"] - r["truth_deg"] + 180.0) % 360.0 - 180.0)
                  < math.degrees(MODE_RADIUS) for r in recs], dtype=float)
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
    lines += ["", f"raw probabilities: lowest pooled log-loss at k = {best:g}",
              f"leave one fold out ({len(set(folds))} folds, k chosen {min(chosen):g}-"
              f"{max(chosen):g}): log-loss {s['log_loss']:.4f}, Brier {s['brier']:.4f}, "
              f"ECE {s['ece']:.4f}; mean probability {s['mean_p']:.3f} against "
              f"{s['right']:.3f} right"]
    # Platt scaling of the raw probability at that k, fitted on all folds but one.
    raw = table[best]
    held = np.zeros(len(recs))
    for f in sorted(set(folds)):
        out = folds == f
        a, b = fit_platt(raw[~out], y[~out])
        held[out] = calibrate(raw[out], a, b)
    a, b = fit_platt(raw, y)
    s = scores(held, y)
    lines += [f"Platt-scaled (sigmoid(a logit(p) + b), a = {a:.3f}, b = {b:.3f} on all "
              f"folds; not shipped unless it lowers the held-out log-loss), leave one fold out: "
              f"log-loss "
              f"{s['log_loss']:.4f}, Brier {s['brier']:.4f}, ECE {s['ece']:.4f}; mean "
              f"probability {s['mean_p']:.3f} against {s['right']:.3f} right"]
    shipped = table[MODE_SHARPNESS] if MODE_SHARPNESS in table else np.array(
        [best_probability(r, MODE_SHARPNESS) for r in recs])
    p = shipped
    s = scores(p, y)
    edges = np.linspace(0, 1, 11)
    bins = np.minimum((p * 10).astype(int), 9)
    lines += ["", f"reliability of the shipped probabilities (k = {MODE_SHARPNESS:g}, what "
                  f"`Hypothesis.probability` gives): log-loss {s['log_loss']:.4f}, Brier {s['brier']:.4f}, "
                  f"ECE {s['ece']:.4f}", "| predicted | images | right |", "|---|---|---|"]
    for b in range(10):
        if np.any(bins == b):
            lines.append(f"| {edges[b]:.1f}-{edges[b + 1]:.1f} (mean {p[bins == b].mean():.2f}) "
                         f"| {np.sum(bins == b)} | {y[bins == b].mean():.2f} |")
    text = "\n".join(lines) + "\n"
    print(text, end="")
    if args.plot:
        plot(p, y, args.plot, f"shipped mode probabilities ({len(recs)} images, "
             f"{', '.join(sorted({r['folder'] for r in recs}))})")
    if args.markdown:
        write_markdown(args.markdown, __file__, argv, text, fenced=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
