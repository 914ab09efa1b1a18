"""Reports of an evaluation run: tables (Markdown, JSON, CSV) and plots.

Plots, for the protocol's main row:

- ``error_histogram.png``: distribution of the azimuth error (Fig. 8);
- ``per_instance.png``: mean and median error and flip rate of each test instance (Fig. 7
  bottom);
- ``scatter.png``: estimated against true azimuth (front/back confusions
  are the off-diagonal bands 180 degrees away);
- ``worst_cases.png``: the worst estimates drawn on their images, with the
  true box in green and the orientation rose (Fig. 9).
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from posevote._io import atomic_write_text, atomic_write_with
from posevote.evaluation.metrics import confidence_outcomes
from posevote.evaluation.protocols import Protocol

#: Fields of a record, in CSV column order.
RECORD_FIELDS = (
    "row", "split", "image", "instance", "group", "truth_deg", "estimate_deg", "error_deg",
    "found", "score", "probability", "second_deg", "second_score", "second_probability",
    "inplane_deg", "scale", "u", "v",
    "box_x", "box_y", "box_w", "box_h", "truth_box_x", "truth_box_y", "truth_box_w",
    "truth_box_h", "iou", "detected", "seen_instance", "recognised", "instance_margin",
    "half_turn", "seconds",
)


def _fmt(value: Any, digits: int = 1) -> str:
    if value is None:
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def markdown_table(summary: dict[str, Any]) -> str:
    """The rows of a summary as a Markdown table, overall then per group."""
    head = ("| row | group | n | median ° | mean ° | p90 ° | % < 22.5° | % < 45° | flip % "
            "| detected % | recognised % | features kept % | ECE | % right, top 85% "
            "| s / image |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n")
    lines = []
    for row in summary["rows"]:
        if not row.get("available", True):
            lines.append(f"| {row['name']} | – | not available: {row['note']} |"
                         + " |" * 12)
            continue
        if "overall" not in row:
            lines.append(f"| {row['name']} | – | not run |" + " |" * 12)
            continue
        parts = [("all", row["overall"])] + list(row["groups"].items())
        for group, m in parts:
            lines.append(
                f"| {row['name']} | {group} | {m['n']} | {_fmt(m['median'], 2)} "
                f"| {_fmt(m['mean'], 2)} | {_fmt(m['p90'])} | {_fmt(m['under_22_5'])} "
                f"| {_fmt(m['under_45'])} | {_fmt(m.get('flip_rate'))} "
                f"| {_fmt(m['detection_rate'])} "
                f"| {_fmt(m['recognition_rate'])} | {_fmt(row.get('features_kept_percent'))} "
                f"| {_fmt(m.get('ece'), 3)} | {_fmt(m.get('right_top_85'))} "
                f"| {_fmt(m['median_seconds'], 3)} |")
    return head + "\n".join(lines) + "\n"


def _range(spread: dict[str, dict[str, float]], key: str, digits: int = 1) -> str:
    if key not in spread:
        return "–"
    v = spread[key]
    return f"{v['min']:.{digits}f}-{v['max']:.{digits}f} (sd {v['std']:.{digits}f})"


def split_table(summary: dict[str, Any]) -> str:
    """Each row's figures per split (the folds of a cross-validation) and their spread.

    Empty when no row has more than one split.
    """
    head = ("| row | split | n | median ° | mean ° | % < 45° | flip % | detected % |\n"
            "|---|---|---|---|---|---|---|---|\n")
    lines = []
    for row in summary["rows"]:
        splits = row.get("splits") or {}
        if len(splits) < 2:
            continue
        for name, m in splits.items():
            lines.append(f"| {row['name']} | {name} | {m['n']} | {_fmt(m['median'], 2)} "
                         f"| {_fmt(m['mean'], 2)} | {_fmt(m['under_45'])} "
                         f"| {_fmt(m.get('flip_rate'))} | {_fmt(m['detection_rate'])} |")
        spread = row.get("spread", {})
        lines.append(f"| {row['name']} | **spread over {len(splits)} splits** | "
                     f"| {_range(spread, 'median', 2)} | {_range(spread, 'mean')} "
                     f"| {_range(spread, 'under_45')} | {_range(spread, 'flip_rate')} "
                     f"| {_range(spread, 'detection_rate')} |")
    return head + "\n".join(lines) + "\n" if lines else ""


def write_csv(records: Sequence[dict[str, Any]], path: Path) -> None:
    """All records as CSV (atomically)."""

    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(RECORD_FIELDS), extrasaction="ignore")
    writer.writeheader()
    for rec in records:
        writer.writerow({k: ("" if rec.get(k) is None else rec.get(k)) for k in RECORD_FIELDS})
    atomic_write_text(path, buf.getvalue())


def row_steps(preset: str, params: dict[str, Any]) -> str:
    """The steps a row's estimator runs, in order (:func:`posevote.pipeline.describe`)."""
    from posevote.estimator import PoseEstimator
    from posevote.pipeline import Settings, describe

    est = PoseEstimator.from_preset(preset, **params)
    return " → ".join(describe(Settings.of(est.get_params(deep=False))))


def write_report(protocol: Protocol, summary: dict[str, Any],
                 records: Sequence[dict[str, Any]], out: Path) -> None:
    """Write ``summary.json``, ``results.csv``, ``report.md`` and the plots into ``out``."""
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    write_csv(records, out / "results.csv")
    main = protocol.main_row or next((r.name for r in protocol.rows if r.params is not None), "")
    mine = [r for r in records if r["row"] == main]
    plots = []
    if mine:
        plot_error_histogram(mine, out / "error_histogram.png", title=f"{protocol.name}: {main}")
        plot_per_instance(mine, out / "per_instance.png", title=f"{protocol.name}: {main}")
        plot_scatter(mine, out / "scatter.png", title=f"{protocol.name}: {main}")
        plot_worst_cases(mine, out / "worst_cases.png")
        prob, near, right = confidence_outcomes(mine)
        plot_calibration(prob, near, out / "calibration.png", success=right,
                         title=f"{protocol.name}: {main}, the best mode's probability")
        plots = ["error_histogram.png", "per_instance.png", "scatter.png", "worst_cases.png",
                 "calibration.png"]
    sub = "" if summary.get("every", 1) == 1 else (
        f"\n**Subsample**: every {summary['every']}th test image of each split.\n")
    rows = "\n".join(f"- **{r.name}**: " + (
        "not available" if r.params is None else
        ", ".join(f"`{k}={v!r}`" for k, v in r.params.items()) or "the preset as it is")
        + (f" ({r.note})" if r.note else "")
        + ("" if r.params is None else f"; steps: {row_steps(protocol.preset, r.params)}")
        for r in protocol.rows)
    text = (f"# {protocol.name}\n\n{protocol.description}\n{sub}\n"
            f"Every row starts from the `{protocol.preset}` preset (posevote.presets, "
            f"docs/DEFAULTS.md) and changes:\n\n{rows}\n\n{markdown_table(summary)}\n"
            "ECE: the expected calibration error of the best mode's probability against its "
            "event (the truth within 30°, the box found where it is known); % right, top 85%: "
            "the share under 45° (box found) of the 85% of images whose best mode is the most "
            "probable.\n\n"
            + (f"Per split, with the spread over the splits (flip: error over 135°, or over "
               f"67.5° on the half circle):\n\n{split_table(summary)}\n"
               if split_table(summary) else "")
            + (f"Published numbers to compare with:\n\n{protocol.published}\n"
               if protocol.published else "")
            + (f"Plots ({main}):\n\n" + "\n".join(f"![{p}]({p})" for p in plots) + "\n"
               if plots else ""))
    atomic_write_text(out / "report.md", text)


def _figure() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: Path) -> None:
    atomic_write_with(path, lambda tmp: fig.savefig(tmp, dpi=100, bbox_inches="tight"))
    _figure().close(fig)


def _flip_rate(records: Sequence[dict[str, Any]]) -> float:
    from posevote.evaluation.metrics import flip_threshold_deg, summarize_errors

    return summarize_errors([r["error_deg"] for r in records], flip_deg=[
        flip_threshold_deg(bool(r.get("half_turn"))) for r in records])["flip_rate"]


def plot_error_histogram(records: Sequence[dict[str, Any]], path: Path, *, title: str = "") -> None:
    """Histogram of the azimuth errors, 5-degree bins (Fig. 8)."""
    plt = _figure()
    err = np.array([r["error_deg"] for r in records], dtype=float)
    fig, ax = plt.subplots(figsize=(6, 3.2))
    ax.hist(err, bins=np.arange(0, 185, 5), color="0.35")
    ax.set_xlabel("azimuth error (degrees)")
    ax.set_ylabel("test images")
    ax.set_title(f"{title}  (median {np.median(err):.1f}°, mean {err.mean():.1f}°, "
                 f"flips {_flip_rate(records):.1f}%)", fontsize=9)
    _save(fig, path)


def plot_per_instance(records: Sequence[dict[str, Any]], path: Path, *, title: str = "") -> None:
    """Mean and median error per test instance (Fig. 7 bottom)."""
    plt = _figure()
    names = sorted({r["instance"] for r in records})
    err = [np.array([r["error_deg"] for r in records if r["instance"] == n]) for n in names]
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(max(4, 0.6 * len(names) + 2), 3.2))
    ax.bar(x - 0.2, [e.mean() for e in err], 0.4, label="mean", color="0.6")
    ax.bar(x + 0.2, [np.median(e) for e in err], 0.4, label="median", color="0.2")
    ax.set_xticks(x, names, rotation=45, ha="right", fontsize=8)
    ax.set_ylabel("azimuth error (degrees)")
    flips = ax.twinx()
    flips.plot(x, [_flip_rate([r for r in records if r["instance"] == n]) for n in names],
               "o", color="tab:red", label="flip rate")
    flips.set_ylim(0, 100)
    flips.set_ylabel("flips (% of test images)", color="tab:red")
    handles = ax.get_legend_handles_labels()[0] + flips.get_legend_handles_labels()[0]
    ax.legend(handles=handles, fontsize=8)
    ax.set_title(title, fontsize=9)
    _save(fig, path)


def plot_scatter(records: Sequence[dict[str, Any]], path: Path, *, title: str = "") -> None:
    """Estimated against true azimuth."""
    plt = _figure()
    found = [r for r in records if r.get("estimate_deg") is not None]
    fig, ax = plt.subplots(figsize=(4, 4))
    ax.scatter([r["truth_deg"] for r in found], [r["estimate_deg"] for r in found], s=4,
               color="0.2")
    ax.plot([0, 360], [0, 360], color="tab:green", lw=0.8)
    ax.set_xlim(0, 360)
    ax.set_ylim(0, 360)
    ax.set_xlabel("true azimuth (degrees)")
    ax.set_ylabel("estimated azimuth (degrees)")
    ax.set_title(f"{title}\nflips {_flip_rate(records):.1f}% (the bands 180° off)", fontsize=9)
    _save(fig, path)


def plot_worst_cases(records: Sequence[dict[str, Any]], path: Path, *, n: int = 12) -> None:
    """The ``n`` worst estimates drawn on their images (Fig. 9 style)."""
    from posevote.data.images import read_image
    from posevote.evaluation.plots import draw_overlay
    from posevote.results import Hypothesis, PoseEstimate

    plt = _figure()
    worst = sorted(records, key=lambda r: -r["error_deg"])[:n]
    cols = 4
    rows = max(1, int(np.ceil(len(worst) / cols)))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.6 * rows), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, rec in zip(axes.ravel(), worst, strict=False):
        try:
            img = read_image(rec["image"])
        except (OSError, ValueError):
            continue
        if rec.get("estimate_deg") is None:
            est = PoseEstimate(found=False, best=None)
        else:
            hyp = Hypothesis(azimuth=np.radians(rec["estimate_deg"]), elevation=0.0,
                             inplane=np.radians(rec.get("inplane_deg") or 0.0),
                             scale=rec.get("scale") or 1.0, position=(rec["u"], rec["v"]),
                             box=(rec["box_x"], rec["box_y"], rec["box_w"], rec["box_h"]),
                             score=rec["score"], refined=True)
            est = PoseEstimate(found=True, best=hyp, modes=(hyp,))
        keys = ("truth_box_x", "truth_box_y", "truth_box_w", "truth_box_h")
        truth = [float(rec[k]) for k in keys] if all(rec.get(k) is not None for k in keys) \
            else None
        canvas = draw_overlay(img, est, truth_box=truth,
                              label=f"true {rec['truth_deg']:.0f} est "
                                    f"{_fmt(rec.get('estimate_deg'), 0)}")
        ax.imshow(canvas[:, :, ::-1])
        ax.set_title(f"{Path(rec['image']).name}: error {rec['error_deg']:.0f}°", fontsize=8)
    fig.suptitle("Worst cases (red: estimate, green: true box; rose: estimated orientation)",
                 fontsize=9)
    _save(fig, path)


def plot_calibration(confidence: Sequence[float], right: Sequence[bool], path: Path, *,
                     title: str = "", success: Sequence[bool] | None = None) -> None:
    """The reliability diagram (the rate of the probability's event, ``right``, against the
    stated probability, per bin, with the counts) beside the risk-coverage curve (the rate of
    ``success``, by default ``right``, among the most confident share)."""
    from posevote.evaluation.metrics import calibration, risk_coverage

    plt = _figure()
    fig, (left, right_ax) = plt.subplots(1, 2, figsize=(10, 3.8))
    cal = calibration(confidence, right)
    bins = np.array([b for b in cal["bins"] if b[2] > 0], dtype=np.float64)
    left.plot([0, 1], [0, 1], color="grey", lw=0.8, ls="--")
    if bins.size:
        left.bar((bins[:, 0] + bins[:, 1]) / 2, bins[:, 4], width=bins[:, 1] - bins[:, 0],
                 alpha=0.5, edgecolor="k", label="right rate")
        left.plot(bins[:, 3], bins[:, 4], "o-", label="per bin")
        for b in bins:
            left.annotate(f"{int(b[2])}", ((b[0] + b[1]) / 2, min(b[4] + 0.03, 0.97)),
                          ha="center", fontsize=7)
    left.set(xlabel="probability of the best mode", ylabel="share right", xlim=(0, 1),
             ylim=(0, 1), title=f"reliability (ECE {cal['ece']:.3f}, n {cal['n']})")
    cov, acc = risk_coverage(confidence, right if success is None else success)
    right_ax.plot(100 * cov, 100 * acc)
    right_ax.set(xlabel="% of estimates kept (most confident first)", ylabel="% right",
                 xlim=(0, 100), ylim=(0, 101), title="risk-coverage")
    fig.suptitle(title, fontsize=9)
    _save(fig, path)
