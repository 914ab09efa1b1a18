"""Appearance descriptors of boxes: HOG of the crop, resized to a fixed window.

Unlike the edge votes, the HOG descriptor (:mod:`posevote.features.hog`) of a
box also sees where edges are *missing* and the shading inside it, which tells
a car's front from its back. The model stores one per training view
(:mod:`posevote.appearance.model`); the verification and the appearance step
compare test boxes with them.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from posevote.features.hog import HOG_CELL, hog

#: Height of the descriptor window, pixels; its width follows the training boxes' shape.
WINDOW_HEIGHT = 48


def window_shape(box_sizes: NDArray[np.float64]) -> tuple[int, int]:
    """Descriptor window ``(height, width)`` for training boxes ``(w, h)`` (median aspect).

    The height is :data:`WINDOW_HEIGHT`; the width is the median box aspect
    times that, rounded to whole 8-pixel cells and kept within 3-18 cells.
    """
    aspect = float(np.median(box_sizes[:, 0] / box_sizes[:, 1])) if len(box_sizes) else 1.0
    cells = int(np.clip(round(WINDOW_HEIGHT * aspect / HOG_CELL), 3, 18))
    return WINDOW_HEIGHT, cells * HOG_CELL


def crop_box(image: NDArray[np.floating], box: Sequence[float]) -> NDArray[np.floating]:
    """The pixels of ``image`` in ``box`` ``(x, y, w, h)`` (rounded; cut off at the borders)."""
    x, y, w, h = (float(b) for b in box)
    x0, y0 = max(int(round(x)), 0), max(int(round(y)), 0)
    x1, y1 = min(int(round(x + w)), image.shape[1]), min(int(round(y + h)), image.shape[0])
    return image[y0:max(y1, y0), x0:max(x1, x0)]


def box_descriptor(image: NDArray[np.floating], box: Sequence[float],
                   window: tuple[int, int]) -> NDArray[np.float32] | None:
    """HOG descriptor of the crop of ``image`` in ``box`` resized to ``window``.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey image.
    box : (x, y, w, h)
        Box in pixels; the part outside the image is cut off.
    window : (height, width)
        Window the crop is resized to (:func:`window_shape`).

    Returns
    -------
    ndarray of float32, or None
        None when less than 8x8 pixels of the box are in the image.
    """
    region = crop_box(image, box)
    if region.shape[0] < 8 or region.shape[1] < 8:
        return None
    # A single-precision image is read in place (OpenCV takes the rows' stride).
    crop = cv2.resize(region if region.dtype == np.float32 else region.astype(np.float32),
                      (window[1], window[0]), interpolation=cv2.INTER_AREA)
    return hog(crop)
