"""Scores of estimates against the truth (the paper's metrics)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from posevote.geometry import box_iou

__all__ = ["FLIP_DEG", "accuracy_at_coverage", "average_precision", "box_iou", "calibration",
           "confidence_outcomes", "flip_threshold_deg", "risk_coverage", "summarize_errors"]

#: An error past this is a flip: the object taken for its half-turned (or mirrored) self.
FLIP_DEG = 135.0


def flip_threshold_deg(half_turn: bool) -> float:
    """The flip threshold: 135 degrees, or 67.5 on the half circle (a quarter-turn confusion)."""
    return FLIP_DEG / 2.0 if half_turn else FLIP_DEG


def summarize_errors(errors_deg: ArrayLike, *, flip_deg: ArrayLike = FLIP_DEG
                     ) -> dict[str, float]:
    """Median, mean, 90th percentile, % under 22.5 / 45 degrees (Fig. 7) and the flip rate.

    Parameters
    ----------
    errors_deg : array_like
        Absolute angular errors, degrees.
    flip_deg : float or array_like, optional
        The error past which an estimate counts as a flip, one value or one
        per error (:func:`flip_threshold_deg`).

    Returns
    -------
    dict
        ``median``, ``mean``, ``p90`` (degrees), ``under_22_5``, ``under_45``,
        ``flip_rate`` (percent) and ``n``.
    """
    e = np.asarray(errors_deg, dtype=np.float64).ravel()
    if e.size == 0:
        raise ValueError("errors_deg is empty")
    if not np.all(np.isfinite(e)):
        raise ValueError("errors_deg holds NaN or infinite values")
    flip = np.broadcast_to(np.asarray(flip_deg, dtype=np.float64), e.shape)
    return {
        "median": float(np.median(e)),
        "mean": float(np.mean(e)),
        "p90": float(np.percentile(e, 90)),
        "under_22_5": float(100.0 * np.mean(e < 22.5)),
        "under_45": float(100.0 * np.mean(e < 45.0)),
        "flip_rate": float(100.0 * np.mean(e > flip)),
        "n": int(e.size),
    }


#: Bins of the reliability diagram (equal width over [0, 1]).
CALIBRATION_BINS = 10


def calibration(confidence: ArrayLike, right: ArrayLike, *, bins: int = CALIBRATION_BINS
                ) -> dict[str, Any]:
    """How well a confidence in [0, 1] predicts being right: the expected calibration error
    and the reliability diagram's bins.

    Parameters
    ----------
    confidence : array_like
        Each estimate's stated probability of being right.
    right : array_like of bool
        Whether it was.
    bins : int, optional
        Equal-width bins over [0, 1].

    Returns
    -------
    dict
        ``ece`` (the bins' mean |right rate - mean confidence|, weighted by
        their counts), ``bins``: per bin ``[low, high, n, mean confidence,
        right rate]`` (NaN rates where a bin is empty), ``n``.

    Examples
    --------
    >>> calibration([0.9, 0.9, 0.1, 0.1], [True, True, False, False])["ece"]
    0.1
    """
    p = np.clip(np.asarray(confidence, dtype=np.float64).ravel(), 0.0, 1.0)
    ok = np.asarray(right, dtype=bool).ravel()
    if p.shape != ok.shape:
        raise ValueError(f"confidence has {p.size} values for {ok.size} outcomes")
    edges = np.linspace(0.0, 1.0, bins + 1)
    which = np.minimum((p * bins).astype(int), bins - 1)
    table, ece = [], 0.0
    for b in range(bins):
        sel = which == b
        n = int(sel.sum())
        conf = float(p[sel].mean()) if n else float("nan")
        rate = float(ok[sel].mean()) if n else float("nan")
        if n:
            ece += n / p.size * abs(rate - conf)
        table.append([float(edges[b]), float(edges[b + 1]), n, conf, rate])
    return {"ece": round(ece, 12) if p.size else float("nan"), "bins": table, "n": int(p.size)}


def risk_coverage(confidence: ArrayLike, right: ArrayLike
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The right rate of the most confident estimates, against their share.

    Returns
    -------
    coverage, accuracy : ndarray
        For k = 1..N: k / N, and the share right among the k most confident
        (ties kept in their order).
    """
    p = np.asarray(confidence, dtype=np.float64).ravel()
    ok = np.asarray(right, dtype=bool).ravel()
    order = np.argsort(-p, kind="stable")
    k = np.arange(1, p.size + 1)
    return k / max(p.size, 1), np.cumsum(ok[order]) / k


def accuracy_at_coverage(confidence: ArrayLike, right: ArrayLike, coverage: float) -> float:
    """The right rate of the most confident ``coverage`` share of the estimates."""
    cov, acc = risk_coverage(confidence, right)
    if cov.size == 0:
        return float("nan")
    return float(acc[max(int(np.ceil(coverage * cov.size)) - 1, 0)])


def average_precision(scores: ArrayLike, hits: ArrayLike, n_positives: int) -> float:
    """The area under the precision-recall curve of detections ranked by score (every
    point interpolated, as PASCAL VOC's).

    Parameters
    ----------
    scores : array_like
        Each detection's score.
    hits : array_like of bool
        Whether it found an object (a true positive).
    n_positives : int
        Objects there were to find.

    Examples
    --------
    >>> average_precision([0.9, 0.8, 0.1], [True, False, True], 2)
    0.8333333333333333
    """
    s = np.asarray(scores, dtype=np.float64).ravel()
    tp = np.asarray(hits, dtype=bool).ravel()
    if n_positives <= 0:
        return float("nan")
    order = np.argsort(-s, kind="stable")
    tp = tp[order]
    cum_tp = np.cumsum(tp)
    precision = cum_tp / np.arange(1, tp.size + 1)
    recall = cum_tp / n_positives
    # The precision envelope, then its area over the recall steps.
    envelope = np.maximum.accumulate(precision[::-1])[::-1]
    steps = np.diff(np.concatenate([[0.0], recall]))
    return float(np.sum(steps * envelope))


#: A mode's probability is that the truth lies within this many degrees of it
#: (:data:`posevote.geometry.MODE_RADIUS`).
MODE_RADIUS_DEG = 30.0


def confidence_outcomes(records: Sequence[dict[str, Any]]
                        ) -> tuple[list[float], list[bool], list[bool]]:
    """Each record's stated probability (0 without a pose), whether its pose is within 30
    degrees (the probability's event), and whether it is right (under 45 degrees); each with
    its box found (IoU 0.5) where the true box is known."""
    prob = [r.get("probability") or 0.0 for r in records]
    boxed = [r.get("detected") is not False for r in records]
    near = [b and r["error_deg"] < MODE_RADIUS_DEG for r, b in zip(records, boxed, strict=True)]
    right = [b and r["error_deg"] < 45.0 for r, b in zip(records, boxed, strict=True)]
    return prob, near, right
