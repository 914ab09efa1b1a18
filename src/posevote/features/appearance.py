"""Appearance descriptors of boxes: HOG of the crop, resized to a fixed window.

Beyond the paper. Unlike the edge votes, a histogram-of-oriented-gradients
descriptor (:func:`skimage.feature.hog`) of a box also sees where edges are
*missing* and the shading inside it, which tells a car's front from its
back. The model stores one per training view (:mod:`posevote.model.appearance`);
the verification and the appearance refinement compare test boxes with them.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

#: Height of the descriptor window, pixels; its width follows the training boxes' shape.
WINDOW_HEIGHT = 48
_CELL = 8


def window_shape(box_sizes: NDArray[np.float64]) -> tuple[int, int]:
    """Descriptor window ``(height, width)`` for training boxes ``(w, h)`` (median aspect).

    The height is :data:`WINDOW_HEIGHT`; the width is the median box aspect
    times that, rounded to whole 8-pixel cells and kept within 3-18 cells.
    """
    aspect = float(np.median(box_sizes[:, 0] / box_sizes[:, 1])) if len(box_sizes) else 1.0
    cells = int(np.clip(round(WINDOW_HEIGHT * aspect / _CELL), 3, 18))
    return WINDOW_HEIGHT, cells * _CELL


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
    from skimage.feature import hog

    crop = cv2.resize(np.ascontiguousarray(region, dtype=np.float32),
                      (window[1], window[0]), interpolation=cv2.INTER_AREA)
    return hog(crop, orientations=9, pixels_per_cell=(_CELL, _CELL), cells_per_block=(2, 2),
               feature_vector=True).astype(np.float32)


def descriptor_length(window: tuple[int, int]) -> int:
    """Length of a :func:`box_descriptor` for ``window``."""
    blocks_y, blocks_x = window[0] // _CELL - 1, window[1] // _CELL - 1
    return blocks_y * blocks_x * 4 * 9
