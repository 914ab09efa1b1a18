"""Scores of estimates against the truth (the paper's metrics)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray


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


def box_iou(box_a: ArrayLike, box_b: ArrayLike) -> NDArray[np.float64]:
    """Intersection over union of ``(x, y, w, h)`` boxes (broadcastable)."""
    a = np.asarray(box_a, dtype=np.float64)
    b = np.asarray(box_b, dtype=np.float64)
    x0 = np.maximum(a[..., 0], b[..., 0])
    y0 = np.maximum(a[..., 1], b[..., 1])
    x1 = np.minimum(a[..., 0] + a[..., 2], b[..., 0] + b[..., 2])
    y1 = np.minimum(a[..., 1] + a[..., 3], b[..., 1] + b[..., 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    union = a[..., 2] * a[..., 3] + b[..., 2] * b[..., 3] - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)
