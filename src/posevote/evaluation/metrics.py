"""Scores of estimates against the truth (the paper's metrics)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from posevote.geometry import box_iou

__all__ = ["FLIP_DEG", "box_iou", "flip_threshold_deg", "summarize_errors"]

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
