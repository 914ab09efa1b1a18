"""The appearance model: training views' descriptors, an objectness classifier, box regressions.

Beyond the paper, for full cluttered frames (the ``category`` preset). At
training time every view's box is described (:mod:`posevote.appearance.descriptors`);
a linear classifier (scikit-learn's :class:`~sklearn.svm.LinearSVC`) learns
object against random boxes of the training images that miss the object
(:func:`background_boxes`, :func:`train_objectness`), and ridge regressions
per azimuth range learn to move a box toward the object from boxes jittered
around the training boxes (:func:`train_box_regression`). The test side is
:mod:`posevote.appearance.verify` and
:mod:`posevote.appearance.refine`.
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numpy.typing import NDArray

from posevote.appearance.descriptors import box_descriptor, crop_box, window_shape
from posevote.features.hog import descriptor_length
from posevote.geometry import box_iou
from posevote.model.density import PoseModel
from posevote.model.training import AppearanceModel

#: Jittered boxes per training image for the box regression, and their spread:
#: centre shifts up to this fraction of the box size, log-size changes up to
#: this much, log-aspect changes up to half of it.
JITTER_PER_IMAGE = 8
JITTER = 0.15
#: Azimuth ranges with a regression of their own (each fitted on the training
#: views within one range width of its centre), the ridge penalty, and the times
#: the regression is applied to a box: chosen on epfl-cv (docs/DEFAULTS.md).
REGRESSION_BINS = 8
REGRESSION_ALPHA = 100.0
REGRESSION_STEPS = 3
_MIN_BIN_SAMPLES = 20


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
    from sklearn.svm import LinearSVC

    x = np.vstack([positives, negatives])
    y = np.r_[np.ones(len(positives)), np.zeros(len(negatives))]
    clf = LinearSVC(C=0.01, class_weight="balanced", random_state=0).fit(x, y)
    return np.r_[clf.coef_[0], clf.intercept_[0]].astype(np.float64)


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
    from sklearn.linear_model import Ridge

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


class AppearanceCollector:
    """Gathers the training images' descriptors while ``fit`` reads them, one image at a time
    (a :class:`~posevote.model.training.ViewCollector`).

    With the descriptor window known from the start (every box given), each
    image's descriptors are computed at once; otherwise (boxes from masks or
    whole images) the crops are kept until every box, hence the window, is
    known. Boxes jittered around each training box are described too, with
    the offsets back to it: the samples of the box regression.
    """

    def __init__(self, boxes: NDArray[np.float64]) -> None:
        known = bool(np.all(np.isfinite(boxes)) and np.all(boxes[:, 2:] > 0))
        self.window: tuple[int, int] | None = window_shape(boxes[:, 2:]) if known else None
        self.rng = np.random.default_rng(0)   # background boxes: same data, same model
        # A generator of its own, so that the background boxes do not depend on it.
        self.jitter_rng = np.random.default_rng(1)
        self.views: list[NDArray[np.float32] | None] = []
        self.backgrounds: list[NDArray[np.float32] | None] = []
        self.jittered: list[NDArray[np.float32] | None] = []
        self.offsets: list[NDArray[np.float64]] = []
        self.azimuths: list[float] = []

    def _describe(self, image: NDArray[np.floating], box: Sequence[float]
                  ) -> NDArray[np.float32] | None:
        if self.window is not None:
            return box_descriptor(image, box, self.window)
        return crop_box(image, box).astype(np.float32)

    def read(self, image: NDArray[np.float64], box: NDArray[np.float64],
             mask: NDArray[np.bool_] | None, pose: NDArray[np.float64]) -> NDArray[np.float32]:
        """The image in single precision, which the descriptors read (in the reading thread)."""
        return image.astype(np.float32)

    def add(self, index: int, read: NDArray[np.float32], box: NDArray[np.float64],
            pose: NDArray[np.float64]) -> None:
        """:meth:`describe` the image read, in the images' order (the boxes are drawn at random)."""
        self.describe(read, box.tolist(), float(pose[0]))

    def with_earlier(self, full: PoseModel, size: NDArray[np.float64]) -> None:
        """Refused: the classifier and the regressions are trained on every image's crops."""
        raise ValueError("the appearance model is learnt from every training image: fit it "
                         "again on all the images")

    def onto_model(self, model: PoseModel, scales: NDArray[np.float64]) -> PoseModel:
        """The model as it is (the appearance model is kept apart)."""
        return model

    def learnt(self, sizes: NDArray[np.float64], n_threads: int) -> dict[str, AppearanceModel]:
        """``{"appearance": ...}``: :meth:`finish`."""
        return {"appearance": self.finish(sizes, n_threads)}

    def describe(self, image: NDArray[np.floating], box: Sequence[float], azimuth: float) -> None:
        """Describe one training image's box, some background boxes and jittered boxes of it."""
        self.views.append(self._describe(image, box))
        self.backgrounds += [self._describe(image, b)
                             for b in background_boxes(image.shape, box, self.rng)]
        for b in jittered_boxes(box, self.jitter_rng):
            self.jittered.append(self._describe(image, b))
            self.offsets.append(box_offsets(b, box))
            self.azimuths.append(azimuth)

    def finish(self, sizes: NDArray[np.float64], n_threads: int = 1) -> AppearanceModel:
        """The appearance model, once every image was added (``sizes``: the boxes' w, h).

        With ``n_threads`` > 1 the classifier is trained in a thread of its
        own while the box regressions are fitted (the same model).
        """
        window = self.window if self.window is not None else window_shape(sizes)

        def stack(items: list[NDArray[np.float32] | None]) -> NDArray[np.float32]:
            out = np.zeros((len(items), descriptor_length(window)), dtype=np.float32)
            for i, item in enumerate(items):
                if item is not None and self.window is None:
                    item = box_descriptor(item, (0, 0, item.shape[1], item.shape[0]), window)
                if item is not None:
                    out[i] = item
            return out

        views, background = stack(self.views), stack(self.backgrounds)
        positives = views[np.any(views != 0, axis=1)]
        negatives = background[np.any(background != 0, axis=1)]
        pool = ThreadPoolExecutor(max_workers=1) if n_threads > 1 else None
        # liblinear runs on one core and releases the GIL; the regressions use BLAS.
        pending = None if pool is None else pool.submit(train_objectness, positives, negatives)
        try:
            samples = stack(self.jittered)
            ok = np.any(samples != 0, axis=1)
            regressor = None
            if ok.sum() >= 2:
                regressor = train_box_regression(samples[ok], np.array(self.offsets)[ok],
                                                 np.array(self.azimuths)[ok])
            objectness = train_objectness(positives, negatives) if pending is None \
                else pending.result()
        finally:
            if pool is not None:
                pool.shutdown(wait=True)
        return AppearanceModel(window=window, descriptors=views, objectness=objectness,
                               regressor=regressor)
