"""Scores of estimates against the truth (the paper's metrics)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from posevote.geometry import box_iou

__all__ = ["box_iou", "summarize_errors"]


def summarize_errors(errors_deg: ArrayLike) -> dict[str, float]:
    """Median, mean, 90th percentile and % under 22.5 / 45 degrees (Fig. 7).

    Parameters
    ----------
    errors_deg : array_like
        Absolute angular errors, degrees.

    Returns
    -------
    dict
        ``median``, ``mean``, ``p90`` (degrees), ``under_22_5``, ``under_45``
        (percent) and ``n``.
    """
    e = np.asarray(errors_deg, dtype=np.float64).ravel()
    if e.size == 0:
        raise ValueError("errors_deg is empty")
    if not np.all(np.isfinite(e)):
        raise ValueError("errors_deg holds NaN or infinite values")
    return {
        "median": float(np.median(e)),
        "mean": float(np.mean(e)),
        "p90": float(np.percentile(e, 90)),
        "under_22_5": float(100.0 * np.mean(e < 22.5)),
        "under_45": float(100.0 * np.mean(e < 45.0)),
        "n": int(e.size),
    }
