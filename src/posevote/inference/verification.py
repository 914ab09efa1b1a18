"""Appearance verification of search candidates (beyond the paper).

The voting search of Fig. 2 ranks (viewpoint, in-plane angle, scale,
translation) probes by how many model edges the image explains there. In a
full cluttered frame the best-scoring probe is often a part of the object
at too small a scale, or clutter, while a probe a little lower in the
ranking has the right box. Verification looks at the image *inside* each of
the best candidates' boxes: a histogram-of-oriented-gradients descriptor
(:func:`skimage.feature.hog`) of the crop, resized to a fixed window, is
compared with the descriptors of the training views near the candidate's
viewpoint, and the candidate whose crop is nearest to one of them wins.
Unlike the edge votes, the descriptor also sees where edges are *missing*
and the shading inside the box, which tells a car's front from its back.

Training views store their descriptor (:func:`view_descriptors`); the test
side is :func:`verify_candidates`. The estimator then re-estimates inside
the winning box (``PoseEstimator(verify_candidates=N)``).
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray
from skimage.feature import hog

from posevote.geometry import viewing_direction
from posevote.inference.search import ProbeSet

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
    x, y, w, h = (float(b) for b in box)
    x0, y0 = max(int(round(x)), 0), max(int(round(y)), 0)
    x1, y1 = min(int(round(x + w)), image.shape[1]), min(int(round(y + h)), image.shape[0])
    if x1 - x0 < 8 or y1 - y0 < 8:
        return None
    crop = cv2.resize(np.ascontiguousarray(image[y0:y1, x0:x1], dtype=np.float32),
                      (window[1], window[0]), interpolation=cv2.INTER_AREA)
    return hog(crop, orientations=9, pixels_per_cell=(_CELL, _CELL), cells_per_block=(2, 2),
               feature_vector=True).astype(np.float32)


def descriptor_length(window: tuple[int, int]) -> int:
    """Length of a :func:`box_descriptor` for ``window``."""
    blocks_y, blocks_x = window[0] // _CELL - 1, window[1] // _CELL - 1
    return blocks_y * blocks_x * 4 * 9


def verify_candidates(probes: ProbeSet, image: NDArray[np.float64],
                      descriptors: NDArray[np.float32], view_azimuth: NDArray[np.float64],
                      view_elevation: NDArray[np.float64], *, window: tuple[int, int],
                      n_candidates: int, tolerance: float
                      ) -> tuple[tuple[int, int, int], float] | None:
    """The search candidate whose crop looks most like a training view near its viewpoint.

    Parameters
    ----------
    probes : ProbeSet
        The search's probes.
    image : ndarray, shape (H, W)
        The grey test image.
    descriptors : ndarray, shape (K, D)
        Descriptor of each training view (:func:`box_descriptor`).
    view_azimuth, view_elevation : ndarray, shape (K,)
        Training viewpoints, radians.
    window : (height, width)
        Descriptor window.
    n_candidates : int
        How many of the best probes (highest p(w)) are verified.
    tolerance : float
        A candidate is compared with the training views within this angle of
        its viewpoint, radians.

    Returns
    -------
    ((viewpoint, inplane, scale), distance) or None
        Indices of the winning probe and its descriptor distance; None if no
        candidate has a descriptor (boxes outside the image) or a training
        view within ``tolerance``.
    """
    order = np.argsort(-probes.score, axis=None, kind="stable")[:n_candidates]
    train_dirs = viewing_direction(view_azimuth, view_elevation)
    cos_tol = np.cos(tolerance)
    train_sq = np.einsum("ij,ij->i", descriptors, descriptors)
    best: tuple[tuple[int, int, int], float] | None = None
    for flat in order:
        v, a, s = (int(i) for i in np.unravel_index(flat, probes.score.shape))
        if probes.score[v, a, s] <= 0:
            break
        near = train_dirs @ probes.directions[v] >= cos_tol
        if not near.any():
            continue
        size = probes.box[v] * probes.scale[s]
        centre = probes.translation[v, a, s]
        d = box_descriptor(image, (centre[0] - size[0] / 2, centre[1] - size[1] / 2,
                                   size[0], size[1]), window)
        if d is None:
            continue
        sq = train_sq[near] + float(d @ d) - 2.0 * (descriptors[near] @ d)
        dist = float(np.sqrt(max(float(sq.min()), 0.0)))
        if best is None or dist < best[1]:
            best = ((v, a, s), dist)
    return best
