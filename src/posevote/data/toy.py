"""A toy object drawn at known azimuths: training and test views with nothing to download.

The docstrings' examples train and estimate on it. The object is an L-shaped
plate with a notch, a round marker on its front face and a stripe, seen on a
turntable: its outline narrows as it turns, and the marker tells its front
from its back.
"""

from __future__ import annotations

from collections.abc import Iterable

import cv2
import numpy as np
from numpy.typing import NDArray

from posevote.data.training_set import object_box

#: Side of a toy view, pixels.
TOY_SIZE = 128


def toy_view(azimuth: float) -> NDArray[np.float64]:
    """The toy object seen from ``azimuth`` (radians): a grey image on black, float in [0, 1]."""
    img = np.zeros((TOY_SIZE, TOY_SIZE), np.float32)
    c = np.array([TOY_SIZE / 2.0, TOY_SIZE / 2.0])
    squash = 0.35 + 0.65 * abs(np.cos(azimuth))
    side = 1.0 if np.cos(azimuth) >= 0 else -1.0
    pts = np.array([[-30, -30], [10, -30], [10, -5], [30, -5], [30, 30], [-30, 30]], float)
    pts[:, 0] = pts[:, 0] * squash * side + 12 * np.sin(azimuth)
    cv2.fillPoly(img, [np.round(pts + c).astype(np.int32)], 0.8, lineType=cv2.LINE_AA)
    marker = np.array([-15.0 * squash * side + 12 * np.sin(azimuth), 12.0]) + c
    cv2.circle(img, tuple(int(round(x)) for x in marker), 6, 0.3, -1, lineType=cv2.LINE_AA)
    stripe = int(round(c[0] + 12 * np.sin(azimuth) + 20 * np.sin(2 * azimuth)))
    cv2.line(img, (stripe, int(c[1] - 25)), (stripe, int(c[1] + 25)), 0.45, 2, cv2.LINE_AA)
    return img.astype(np.float64)


def toy_views(azimuths_deg: Iterable[float]
              ) -> tuple[list[NDArray[np.float64]], NDArray[np.float64], NDArray[np.float64]]:
    """The toy object at each azimuth (degrees), with its poses and boxes.

    Returns
    -------
    images : list of ndarray, shape (128, 128)
    poses : ndarray, shape (K,)
        The azimuths, radians (what :meth:`posevote.PoseEstimator.fit` takes).
    boxes : ndarray, shape (K, 4)
        Each view's box ``(x, y, w, h)``.

    Examples
    --------
    >>> images, poses, boxes = toy_views([0, 90])
    >>> len(images), poses.round(3).tolist(), boxes.shape
    (2, [0.0, 1.571], (2, 4))
    """
    poses = np.radians(np.asarray(list(azimuths_deg), dtype=np.float64))
    images = [toy_view(float(a)) for a in poses]
    return images, poses, np.array([object_box(img) for img in images]).reshape(-1, 4)
