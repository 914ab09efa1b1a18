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

Nearness to a training view is judged among the candidates that look most
like the object at all: a linear classifier of the descriptors (scikit-learn's
:class:`~sklearn.svm.LinearSVC`), trained on the training boxes against
boxes of the training images that miss the object (:func:`background_boxes`,
:func:`train_objectness`), short-lists them first. Without the short list
the nearest descriptor often belonged to a part of the object or to a patch
of background that happens to resemble some view.

Training views store their descriptor and the classifier; the test side is
:func:`verify_candidates`. The estimator then re-estimates inside the
winning box (``PoseEstimator(verify_candidates=N)``).
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray
from skimage.feature import hog
from sklearn.linear_model import Ridge
from sklearn.svm import LinearSVC

from posevote.geometry import box_iou, viewing_direction
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
    crop = cv2.resize(np.ascontiguousarray(region, dtype=np.float32),
                      (window[1], window[0]), interpolation=cv2.INTER_AREA)
    return hog(crop, orientations=9, pixels_per_cell=(_CELL, _CELL), cells_per_block=(2, 2),
               feature_vector=True).astype(np.float32)


def descriptor_length(window: tuple[int, int]) -> int:
    """Length of a :func:`box_descriptor` for ``window``."""
    blocks_y, blocks_x = window[0] // _CELL - 1, window[1] // _CELL - 1
    return blocks_y * blocks_x * 4 * 9


def background_boxes(shape: tuple[int, int], box: Sequence[float], rng: np.random.Generator,
                     *, attempts: int = 5, max_overlap: float = 0.4) -> list[tuple[float, ...]]:
    """Random boxes of an image that miss its object (negatives for :func:`train_objectness`).

    Each attempt draws a box of 0.4 to 1.2 times the object box's size (its
    aspect changed by up to a factor 1.35 either way) anywhere in the image,
    and keeps it if its intersection over union with the object box is below
    ``max_overlap``: parts of the object count as background.
    """
    h_img, w_img = shape
    x0, y0, w0, h0 = (float(b) for b in box)
    out: list[tuple[float, ...]] = []
    for _ in range(attempts):
        size = np.exp(rng.uniform(np.log(0.4), np.log(1.2)))
        w = min(w0 * size * np.exp(rng.uniform(-0.3, 0.3)), 0.95 * w_img)
        h = min(h0 * size, 0.95 * h_img)
        x = rng.uniform(-0.05 * w, w_img - 0.95 * w)
        y = rng.uniform(-0.05 * h, h_img - 0.95 * h)
        if box_iou((x, y, w, h), (x0, y0, w0, h0)) < max_overlap:
            out.append((x, y, w, h))
    return out


def train_objectness(positives: NDArray[np.float32], negatives: NDArray[np.float32]
                     ) -> NDArray[np.float64] | None:
    """Linear classifier of descriptors, object against background.

    Parameters
    ----------
    positives, negatives : ndarray, shape (n, D)
        Descriptors of object boxes and of background boxes.

    Returns
    -------
    ndarray, shape (D + 1,), or None
        Weights and bias (score ``d @ w[:-1] + w[-1]``, positive for the
        object); None with fewer than 10 negatives or 2 positives.
    """
    if len(negatives) < 10 or len(positives) < 2:
        return None
    x = np.vstack([positives, negatives])
    y = np.r_[np.ones(len(positives)), np.zeros(len(negatives))]
    clf = LinearSVC(C=0.01, class_weight="balanced", random_state=0).fit(x, y)
    return np.r_[clf.coef_[0], clf.intercept_[0]].astype(np.float64)


def verify_candidates(probes: ProbeSet, image: NDArray[np.float64],
                      descriptors: NDArray[np.float32], view_azimuth: NDArray[np.float64],
                      view_elevation: NDArray[np.float64], *, window: tuple[int, int],
                      n_candidates: int, tolerance: float,
                      objectness: NDArray[np.float64] | None = None, shortlist: int = 10,
                      regressor: NDArray[np.float64] | None = None,
                      objectness_weight: float = 0.0
                      ) -> tuple[tuple[int, int, int], float, tuple[float, ...]] | None:
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
    objectness : ndarray, shape (D + 1,), optional
        Classifier of :func:`train_objectness`; with it, only the
        ``shortlist`` candidates it scores highest are compared.
    shortlist : int, optional
        Size of the short list.
    regressor : ndarray, shape (B, 4, D + 1), optional
        Box regressions (:func:`train_box_regression`); with them, each
        short-listed candidate's box is first regressed
        (:func:`regress_described`) and the regressed box's descriptor is
        compared.
    objectness_weight : float, optional
        With ``objectness``, a candidate's distance to its nearest training
        view minus this times the classifier's score of the compared
        descriptor decides (0: the distance alone).

    Returns
    -------
    ((viewpoint, inplane, scale), distance, box) or None
        Indices of the winning probe, its (weighted) descriptor distance and the box
        that was compared (the probe's, or its regressed box); None if no
        candidate has a descriptor (boxes outside the image) or a training
        view within ``tolerance``.
    """
    order = np.argsort(-probes.score, axis=None, kind="stable")[:n_candidates]
    train_dirs = viewing_direction(view_azimuth, view_elevation)
    cos_tol = np.cos(tolerance)
    found: list[tuple[tuple[int, int, int], NDArray[np.bool_], NDArray[np.float32]]] = []
    boxes = probes.boxes()
    for flat in order:
        v, a, s = (int(i) for i in np.unravel_index(flat, probes.score.shape))
        if probes.score[v, a, s] <= 0:
            break
        near = train_dirs @ probes.directions[v] >= cos_tol
        if not near.any():
            continue
        d = box_descriptor(image, boxes[v, a, s], window)
        if d is not None:
            found.append(((v, a, s), near, d))
    if not found:
        return None
    if objectness is not None and len(found) > shortlist:
        looks = np.array([float(d @ objectness[:-1]) + objectness[-1] for _, _, d in found])
        found = [found[i] for i in np.sort(np.argsort(-looks, kind="stable")[:shortlist])]
    train_sq = np.einsum("ij,ij->i", descriptors, descriptors)
    best: tuple[tuple[int, int, int], float, tuple[float, ...]] | None = None
    for index, near, d in found:
        v, a, s = index
        box = tuple(float(b) for b in boxes[v, a, s])
        if regressor is not None:
            moved, regressed = regress_described(image, box, d, regressor,
                                                 float(probes.azimuth[v]), window=window)
            if regressed is not None:
                box, d = moved, regressed
        sq = train_sq[near] + float(d @ d) - 2.0 * (descriptors[near] @ d)
        dist = float(np.sqrt(max(float(sq.min()), 0.0)))
        if objectness is not None and objectness_weight:
            dist -= objectness_weight * (float(d @ objectness[:-1]) + objectness[-1])
        if best is None or dist < best[1]:
            best = (index, dist, box)
    return best


# -- box regression and the pose of the regressed box (appearance_refine) -------------

#: Jittered boxes per training image for the box regression, and their spread:
#: centre shifts up to this fraction of the box size, log-size changes up to
#: this much, log-aspect changes up to half of it.
JITTER_PER_IMAGE = 8
JITTER = 0.15
#: Azimuth ranges with a regression of their own (each fitted on the training
#: views within one range width of its centre), and the ridge penalty. Chosen
#: on epfl-cv (every 8th test frame; benchmarks/epfl_box_regression.py,
#: docs/TUNING.md): one regression for all views 8.34, four 8.81, eight 7.84
#: degrees median error after the pose step; penalty 10 / 100 / 1000 left
#: the median IoU at 0.76 / 0.78 / 0.75 (one regression, every second frame).
REGRESSION_BINS = 8
REGRESSION_ALPHA = 100.0
#: Times the regression is applied to a box (median IoU 0.70, 0.74, 0.76, 0.76
#: after 0 to 3 steps on the same frames).
REGRESSION_STEPS = 3
_MIN_BIN_SAMPLES = 20


def jittered_boxes(box: Sequence[float], rng: np.random.Generator, *,
                   n: int = JITTER_PER_IMAGE, jitter: float = JITTER
                   ) -> list[tuple[float, float, float, float]]:
    """Boxes moved and resized at random around ``box`` (training samples of the regression)."""
    x, y, w, h = (float(b) for b in box)
    out = []
    for _ in range(n):
        size = np.exp(rng.uniform(-jitter, jitter))
        aspect = np.exp(rng.uniform(-jitter, jitter) / 2.0)
        nw, nh = w * size * aspect, h * size / aspect
        cx = x + w / 2.0 + rng.uniform(-jitter, jitter) * w
        cy = y + h / 2.0 + rng.uniform(-jitter, jitter) * h
        out.append((cx - nw / 2.0, cy - nh / 2.0, nw, nh))
    return out


def box_offsets(box: Sequence[float], target: Sequence[float]) -> NDArray[np.float64]:
    """From ``box`` to ``target``: centre shift in box widths and heights, log-size ratios."""
    x, y, w, h = (float(b) for b in box)
    tx, ty, tw, th = (float(b) for b in target)
    return np.array([(tx + tw / 2.0 - x - w / 2.0) / w, (ty + th / 2.0 - y - h / 2.0) / h,
                     np.log(tw / w), np.log(th / h)])


def shift_box(box: Sequence[float], offsets: NDArray[np.float64]
              ) -> tuple[float, float, float, float]:
    """``box`` moved by :func:`box_offsets` (the inverse of that function)."""
    x, y, w, h = (float(b) for b in box)
    nw, nh = w * float(np.exp(offsets[2])), h * float(np.exp(offsets[3]))
    cx, cy = x + w / 2.0 + float(offsets[0]) * w, y + h / 2.0 + float(offsets[1]) * h
    return cx - nw / 2.0, cy - nh / 2.0, nw, nh


def train_box_regression(descriptors: NDArray[np.float32], offsets: NDArray[np.float64],
                         azimuths: NDArray[np.float64], *, bins: int = REGRESSION_BINS,
                         alpha: float = REGRESSION_ALPHA) -> NDArray[np.float64]:
    """Ridge regressions from a box's descriptor to the offsets back to the object's box.

    Parameters
    ----------
    descriptors : ndarray, shape (n, D)
        Descriptors (:func:`box_descriptor`) of boxes jittered around the
        training boxes (:func:`jittered_boxes`).
    offsets : ndarray, shape (n, 4)
        :func:`box_offsets` from each jittered box to its training box.
    azimuths : ndarray, shape (n,)
        Azimuth of each sample's training view, radians.
    bins : int, optional
        Azimuth ranges, each with its own regression, fitted on the samples
        within one range width of its centre (all of them when fewer than
        20 are there).
    alpha : float, optional
        Ridge penalty (:class:`sklearn.linear_model.Ridge`).

    Returns
    -------
    ndarray, shape (bins, 4, D + 1)
        Per range, weights and intercept of each offset.
    """
    width = 2.0 * np.pi / bins
    out = np.zeros((bins, 4, descriptors.shape[1] + 1))
    for k in range(bins):
        near = np.abs(np.angle(np.exp(1j * (azimuths - (k + 0.5) * width)))) <= width + 1e-9
        if near.sum() < _MIN_BIN_SAMPLES:
            near = np.ones(len(azimuths), dtype=bool)
        reg = Ridge(alpha=alpha).fit(descriptors[near], offsets[near])
        out[k, :, :-1] = reg.coef_
        out[k, :, -1] = reg.intercept_
    return out


def regress_box(image: NDArray[np.floating], box: Sequence[float], regressor: NDArray[np.float64],
                azimuth: float, *, window: tuple[int, int], steps: int = REGRESSION_STEPS
                ) -> tuple[float, float, float, float]:
    """Move ``box`` toward the object by the regression of its azimuth range, ``steps`` times.

    A box whose descriptor cannot be computed (less than 8x8 pixels in the
    image) stays where it is.
    """
    return regress_described(image, box, box_descriptor(image, box, window), regressor, azimuth,
                             window=window, steps=steps)[0]


def regress_described(image: NDArray[np.floating], box: Sequence[float],
                      descriptor: NDArray[np.float32] | None, regressor: NDArray[np.float64],
                      azimuth: float, *, window: tuple[int, int], steps: int = REGRESSION_STEPS
                      ) -> tuple[tuple[float, float, float, float], NDArray[np.float32] | None]:
    """:func:`regress_box` from the box's ``descriptor``; also returns the moved box's.

    Each step describes the moved box once: ``steps`` descriptors in all,
    the last one the returned box's. A move onto a box that cannot be
    described (less than 8x8 pixels in the image) is not taken; the
    returned descriptor is None only when ``descriptor`` is.
    """
    bins = regressor.shape[0]
    coef = regressor[int(np.mod(azimuth, 2.0 * np.pi) // (2.0 * np.pi / bins)) % bins]
    x, y, w, h = (float(b) for b in box)
    out, d = (x, y, w, h), descriptor
    for _ in range(steps):
        if d is None:
            break
        moved = shift_box(out, coef[:, :-1] @ d + coef[:, -1])
        d_moved = box_descriptor(image, moved, window)
        if d_moved is None:
            break
        out, d = moved, d_moved
    return out, d


def views_within(view_directions: NDArray[np.float64], direction: NDArray[np.float64],
                 window: float) -> NDArray[np.intp]:
    """Indices of the views whose viewing direction lies within ``window`` radians of ``direction``."""
    return np.flatnonzero(view_directions @ direction >= np.cos(window) - 1e-12)


def nearest_view(descriptor: NDArray[np.float32], descriptors: NDArray[np.float32],
                 view_directions: NDArray[np.float64], direction: NDArray[np.float64], *,
                 window: float) -> int | None:
    """The training view whose descriptor is nearest, among those within ``window`` radians.

    Returns its index, or None when no training view is that near ``direction``.
    """
    near = views_within(view_directions, direction, window)
    if len(near) == 0:
        return None
    sq = np.einsum("ij,ij->i", descriptors[near], descriptors[near]) - 2.0 * (
        descriptors[near] @ descriptor)
    return int(near[np.argmin(sq)])


def box_grid(box: Sequence[float], fraction: float) -> NDArray[np.float64]:
    """``box`` and its 26 neighbours: shifted by ``-fraction``, 0 or ``+fraction`` of its
    width and height and scaled by ``1 - fraction``, 1 or ``1 + fraction`` about its centre.

    Returns
    -------
    ndarray, shape (27, 4)
        Boxes ``(x, y, w, h)``; row 13 is ``box`` itself.
    """
    x, y, w, h = (float(b) for b in box)
    steps = (-fraction, 0.0, fraction)
    out = []
    for dx in steps:
        for dy in steps:
            for ds in steps:
                ww, hh = w * (1.0 + ds), h * (1.0 + ds)
                cx, cy = x + 0.5 * w + dx * w, y + 0.5 * h + dy * h
                out.append((cx - 0.5 * ww, cy - 0.5 * hh, ww, hh))
    return np.array(out)


def medoid_view(views: Sequence[int], view_directions: NDArray[np.float64]) -> int:
    """The view of ``views`` whose summed angle to the others' viewing directions is least.

    Views may repeat (each counts once per occurrence); ties go to the first.
    """
    idx = np.asarray(views, dtype=np.intp)
    dirs = view_directions[idx]
    angles = np.arccos(np.clip(dirs @ dirs.T, -1.0, 1.0))
    return int(idx[np.argmin(angles.sum(axis=1))])


def jittered_nearest_view(image: NDArray[np.floating], box: Sequence[float],
                          descriptors: NDArray[np.float32], view_directions: NDArray[np.float64],
                          direction: NDArray[np.float64], *, window: float,
                          descriptor_window: tuple[int, int], fraction: float) -> int | None:
    """:func:`nearest_view` of ``box`` and of its :func:`box_grid`, their :func:`medoid_view`.

    Beyond the paper: the nearest training descriptor of one box jumps
    between views when the box is a few pixels off; the medoid of the
    nearest views of 27 boxes around it does not.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey test image.
    box : (x, y, w, h)
        The estimate's box.
    descriptors, view_directions, direction, window
        As in :func:`nearest_view`.
    descriptor_window : (int, int)
        :func:`window_shape` of the model.
    fraction : float
        Jitter of :func:`box_grid`.

    Returns
    -------
    int or None
        The view's index; None when no training view lies within ``window``
        or no jittered box can be described.
    """
    near = views_within(view_directions, direction, window)
    described = [box_descriptor(image, b, descriptor_window) for b in box_grid(box, fraction)]
    found = np.array([d for d in described if d is not None])
    if len(near) == 0 or len(found) == 0:
        return None
    ref = descriptors[near]
    sq = np.einsum("ij,ij->i", ref, ref)[None, :] - 2.0 * (found @ ref.T)
    return medoid_view(near[np.argmin(sq, axis=1)].tolist(), view_directions)
