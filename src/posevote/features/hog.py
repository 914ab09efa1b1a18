"""HOG, the histogram of oriented gradients of a grey image, as one compiled kernel.

:func:`hog` computes what :func:`skimage.feature.hog` does with this module's
settings (9 orientations, 8-pixel cells, 2 x 2 blocks, L2-Hys);
:func:`hog_reference` calls scikit-image, for the tests. Unlike the edge
points, HOG also sees where edges are missing and the shading between them:
the appearance stages (:mod:`posevote.appearance`) describe boxes with it, and
the half-turn check compares a pose's image with its template by it
(:func:`posevote.templates.match.gradient_similarity`).
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

#: Pixels across a HOG cell (2 x 2 cells a block).
HOG_CELL = 8
_ORIENTATIONS = 9
_HYS_CLIP = 0.2  # L2-Hys: the block's normalised values are clipped here, then renormalised
_EPS = 1e-5


def descriptor_length(window: tuple[int, int]) -> int:
    """Length of a :func:`box_descriptor` for ``window``."""
    blocks_y, blocks_x = window[0] // HOG_CELL - 1, window[1] // HOG_CELL - 1
    return blocks_y * blocks_x * 4 * _ORIENTATIONS

@numba.njit(cache=True, nogil=True)
def _gradient_bins(g_row, g_col, n, edge_cos, magnitude, bins):  # pragma: no cover - compiled
    """Each pixel's gradient magnitude (double) and unsigned orientation bin, over a row.

    The bin is how many edges' cosines lie at or above the direction's
    cosine (they decrease), counted without a branch; the edge count is the
    module's constant, so that the compiler unrolls it and vectorises the
    row.
    """
    for c in range(n):
        y = np.float64(g_row[c])
        x = np.float64(g_col[c])
        m = np.sqrt(x * x + y * y)
        # Unsigned orientation: the direction folded into [0, 180) degrees.
        x = -x if (y < 0.0) | ((y == 0.0) & (x < 0.0)) else x
        cosine = x / (m if m > 0.0 else 1.0)
        b = 0
        for e in range(_ORIENTATIONS - 1):
            b += cosine <= edge_cos[e]
        magnitude[c] = m
        bins[c] = b

@numba.njit(cache=True, nogil=True)
def _hog_kernel(crop, cell, clip, eps, out):  # pragma: no cover - compiled
    """Cell histograms of gradient orientation, then L2-Hys over 2 x 2 blocks, into ``out``.

    As scikit-image: central differences in single precision (0 on the
    border), magnitude in double, each pixel's magnitude into its one
    orientation bin (lower edge inclusive) of the unsigned orientation, the
    cell's mean. The bin is found by comparing the gradient's direction
    cosine with the bin edges' instead of by an arctangent: the same bin
    but within rounding of an edge, for a fraction of the cost. A row's
    gradients and bins are computed first (vectorised), then added up.
    """
    orientations = _ORIENTATIONS
    h, w = crop.shape
    cy, cx = h // cell, w // cell
    hist = np.zeros((cy, cx, orientations))
    # cos of the edges 180 k / orientations, k = 1 .. orientations - 1: decreasing.
    edge_cos = np.cos(np.arange(1, orientations) * (np.pi / orientations))
    # Integer division by a run-time cell size is slow per pixel: once per column.
    col_cell = np.arange(w) // cell
    used = cx * cell  # the columns of whole cells
    g_row = np.zeros(w, dtype=np.float32)
    g_col = np.zeros(w, dtype=np.float32)
    magnitude = np.empty(w)
    bins = np.empty(w, dtype=np.int64)
    for r in range(cy * cell):
        cr = r // cell
        if 0 < r < h - 1:
            for c in range(used):
                g_row[c] = crop[r + 1, c] - crop[r - 1, c]
        else:
            g_row[:] = 0.0
        for c in range(1, min(used, w - 1)):
            g_col[c] = crop[r, c + 1] - crop[r, c - 1]
        _gradient_bins(g_row, g_col, used, edge_cos, magnitude, bins)
        for c in range(used):
            if magnitude[c] > 0.0:
                hist[cr, col_cell[c], bins[c]] += magnitude[c]
    hist /= cell * cell
    k = 0
    block = np.empty(4 * orientations)
    for br in range(cy - 1):
        for bc in range(cx - 1):
            n = 0
            for dr in range(2):
                for dc in range(2):
                    for b in range(orientations):
                        block[n] = hist[br + dr, bc + dc, b]
                        n += 1
            total = 0.0
            for i in range(n):
                total += block[i] * block[i]
            norm = np.sqrt(total + eps * eps)
            total = 0.0
            for i in range(n):
                block[i] = min(block[i] / norm, clip)
                total += block[i] * block[i]
            norm = np.sqrt(total + eps * eps)
            for i in range(n):
                out[k] = block[i] / norm
                k += 1

def hog(crop: NDArray[Any]) -> NDArray[np.float32]:
    """HOG descriptor of a grey crop (at least 16 x 16 pixels), as :func:`hog_reference`."""
    crop = np.ascontiguousarray(crop, dtype=np.float32)
    out = np.empty(descriptor_length(crop.shape[:2]), dtype=np.float64)
    _hog_kernel(crop, HOG_CELL, _HYS_CLIP, _EPS, out)
    return out.astype(np.float32)

def hog_reference(crop: NDArray[np.floating]) -> NDArray[np.float32]:
    """:func:`skimage.feature.hog` with the settings of :func:`hog` (for tests)."""
    from skimage.feature import hog as skimage_hog

    return skimage_hog(np.asarray(crop, dtype=np.float32), orientations=_ORIENTATIONS,
                       pixels_per_cell=(HOG_CELL, HOG_CELL), cells_per_block=(2, 2),
                       block_norm="L2-Hys", feature_vector=True).astype(np.float32)
