"""Edge-point features: position and smoothed tangent orientation (Sec. IV).

A feature lives in the appearance space ``A = R^2 x S^1_+``: its image
position ``(u, v)`` and the orientation of the edge's tangent, an angle in
``[0, pi)`` (an edge has no direction).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from posevote._options import Options
from posevote.data.images import as_gray_float
from posevote.geometry import rotate_points

# Gradients are scaled to int16 for OpenCV's Canny; 1.0 (a grey-level change
# of the whole range per pixel) maps to this many units.
_GRADIENT_UNITS = 4096.0


@dataclass(frozen=True, kw_only=True, repr=False)
class EdgeOptions(Options):
    """How edge features are extracted from training and test images (Sec. IV).

    Attributes
    ----------
    sigma : float, default 1.0
        Canny smoothing, pixels.
    thresholds : (float, float), default (0.02, 0.05)
        Canny hysteresis thresholds, grey levels (full range 1) per pixel;
        lower them for low-contrast objects.
    spacing : float, default 2.0
        Minimum spacing of edge points, pixels.
    max_train_features : int, default 300
        Feature budget per training view.
    max_test_features : int or None, default 2500
        Feature budget per 640 x 480 pixels of test image, never fewer per image
        (:func:`frame_budget`; None: the spacing alone).
    """

    sigma: float = 1.0
    thresholds: tuple[float, float] = (0.02, 0.05)
    spacing: float = 2.0
    max_train_features: int = 300
    max_test_features: int | None = 2500

    def __post_init__(self) -> None:
        self._number("sigma", low=0.0, high=20.0, low_open=True)
        low, high = self._pair("thresholds")
        if not 0 < low <= high <= 1:
            self._fail("thresholds", "(low, high) with 0 < low <= high <= 1", self.thresholds)
        self._number("spacing", low=0.5, high=50.0)
        self._number("max_train_features", low=1, high=100_000, integer=True)
        self._number("max_test_features", low=1, high=1_000_000, integer=True, optional=True)


@dataclass(frozen=True, kw_only=True, eq=False)
class EdgeFeatures:
    """A set of edge points.

    Attributes
    ----------
    xy : ndarray, shape (N, 2)
        Positions ``(u, v)`` in pixels.
    theta : ndarray, shape (N,)
        Tangent orientations in ``[0, pi)``, radians.
    """

    xy: NDArray[np.float64]
    theta: NDArray[np.float64]

    def __len__(self) -> int:
        return int(self.theta.shape[0])

    def select(self, keep: NDArray[np.bool_] | NDArray[np.integer]) -> EdgeFeatures:
        """The features selected by a boolean mask or index array."""
        return EdgeFeatures(xy=self.xy[keep], theta=self.theta[keep])


def _thin_evenly(xy: NDArray[np.float64], *, spacing: float, max_points: int | None
                 ) -> NDArray[np.intp]:
    """Indices of points kept by keeping one point per ``spacing``-sized cell.

    The spacing grows until at most ``max_points`` remain, so points stay evenly
    spread along the edges whatever the budget.
    """
    if len(xy) == 0:
        return np.zeros(0, dtype=np.intp)
    step = max(float(spacing), 1e-9)
    while True:
        cells = np.floor(xy / step).astype(np.int64)
        key = cells[:, 0] * 1_000_003 + cells[:, 1]
        _, first = np.unique(key, return_index=True)
        if max_points is None or len(first) <= max_points:
            return np.sort(first)
        step *= max(1.05, float(np.sqrt(len(first) / max_points)))


def detect_edges(
    image: NDArray,
    *,
    sigma: float = 1.0,
    low_threshold: float = 0.02,
    high_threshold: float = 0.05,
    orientation_sigma: float = 2.0,
    spacing: float = 2.0,
    max_points: int | None = None,
    mask: NDArray[np.bool_] | None = None,
) -> EdgeFeatures:
    """Canny edge points with smoothed tangent orientation (paper Sec. IV).

    Parameters
    ----------
    image : ndarray
        Grey, RGB or RGBA image (uint8, uint16 or float in [0, 1]).
    sigma : float, optional
        Gaussian smoothing before differentiation, pixels.
    low_threshold, high_threshold : float, optional
        Canny hysteresis thresholds on the gradient magnitude, in grey levels
        (full range = 1) per pixel.
    orientation_sigma : float, optional
        Width (pixels) of the structure-tensor smoothing that stabilises the
        orientation estimate.
    spacing : float, optional
        Minimum spacing of the kept points along edges, pixels: one point per
        ``spacing``-sized cell.
    max_points : int, optional
        Budget: the spacing grows until at most this many points remain.
    mask : ndarray of bool, optional
        Keep only edge points where the mask is true.

    Returns
    -------
    EdgeFeatures
        Possibly empty; callers decide whether an edge-less image is an error.

    Raises
    ------
    ValueError
        On an empty image, bad thresholds or a mask of the wrong shape.
    """
    gray = as_gray_float(image)
    if not 0 < low_threshold <= high_threshold:
        raise ValueError(f"thresholds must satisfy 0 < low_threshold <= high_threshold, "
                         f"got {low_threshold}, {high_threshold}")
    if mask is not None and mask.shape != gray.shape:
        raise ValueError(f"mask has shape {mask.shape}, the image {gray.shape}")
    img = np.asarray(gray, dtype=np.float32)
    if sigma > 0:
        img = np.asarray(cv2.GaussianBlur(img, (0, 0), sigmaX=sigma, sigmaY=sigma,
                                          borderType=cv2.BORDER_REPLICATE), dtype=np.float32)
    # Sobel / 8 is the per-pixel derivative of a smooth ramp.
    gx = np.asarray(cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE),
                    dtype=np.float32) / np.float32(8.0)
    gy = np.asarray(cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE),
                    dtype=np.float32) / np.float32(8.0)
    dx = np.clip(np.rint(gx * _GRADIENT_UNITS), -32767, 32767).astype(np.int16)
    dy = np.clip(np.rint(gy * _GRADIENT_UNITS), -32767, 32767).astype(np.int16)
    edges = cv2.Canny(dx, dy, low_threshold * _GRADIENT_UNITS, high_threshold * _GRADIENT_UNITS,
                      L2gradient=True)
    if mask is None:
        rows, cols = np.nonzero(edges)
    else:
        # Read within the mask's bounding box only (row-major, as over the whole image).
        inside_rows = np.flatnonzero(mask.any(axis=1))
        inside_cols = np.flatnonzero(mask.any(axis=0))
        if len(inside_rows) == 0:
            return EdgeFeatures(xy=np.zeros((0, 2)), theta=np.zeros(0))
        r0, r1 = int(inside_rows[0]), int(inside_rows[-1]) + 1
        c0, c1 = int(inside_cols[0]), int(inside_cols[-1]) + 1
        rows, cols = np.nonzero((edges[r0:r1, c0:c1] > 0) & mask[r0:r1, c0:c1])
        rows, cols = rows + r0, cols + c0
    xy = np.stack([cols, rows], axis=1).astype(np.float64)
    keep = _thin_evenly(xy, spacing=spacing, max_points=max_points)
    rows, cols, xy = rows[keep], cols[keep], xy[keep]
    # The dominant gradient orientation from the smoothed structure tensor;
    # the tangent is perpendicular to it.
    # Blurred only around the kept points (a training box is a fraction of
    # its frame): past the blur's reach from the window's inner sides, the
    # values are the whole image's.
    if len(rows):
        reach = int(np.ceil(4 * orientation_sigma)) + 2
        r0, c0 = max(int(rows.min()) - reach, 0), max(int(cols.min()) - reach, 0)
        r1, c1 = int(rows.max()) + reach + 1, int(cols.max()) + reach + 1
        gx, gy, rows, cols = gx[r0:r1, c0:c1], gy[r0:r1, c0:c1], rows - r0, cols - c0
    jxx = cv2.GaussianBlur(gx * gx, (0, 0), orientation_sigma)
    jyy = cv2.GaussianBlur(gy * gy, (0, 0), orientation_sigma)
    jxy = cv2.GaussianBlur(gx * gy, (0, 0), orientation_sigma)
    grad_angle = 0.5 * np.arctan2(2.0 * jxy[rows, cols], jxx[rows, cols] - jyy[rows, cols])
    theta = np.mod(grad_angle.astype(np.float64) + np.pi / 2.0, np.pi)
    return EdgeFeatures(xy=xy, theta=theta)


#: The frame area (pixels) that ``max_test_features`` is the budget of: a 640 x 480 frame's.
BUDGET_AREA = 640 * 480


def frame_budget(options: EdgeOptions, shape: tuple[int, ...]) -> int | None:
    """The feature budget of a test image of ``shape`` (H, W): ``max_test_features`` per
    :data:`BUDGET_AREA` of it, never fewer than ``max_test_features``.

    A larger frame keeps the points' spacing of a 640 x 480 one, and with it what a score
    means: a budget fixed per image thinned a larger frame's points, and lowered its
    scores, the more the larger it was (docs/history/TRUST.md).
    """
    budget = options.max_test_features
    if budget is None:
        return None
    return area_budget(budget, shape)


def area_budget(count: int, shape: tuple[int, ...]) -> int:
    """``count`` per :data:`BUDGET_AREA` of an image of ``shape`` (H, W), never fewer than
    ``count``: what a 640 x 480 frame is given, at the same density on a larger one."""
    return max(count, int(round(count * shape[0] * shape[1] / BUDGET_AREA)))


def extract_edges(image: NDArray, options: EdgeOptions, *, training: bool,
                  mask: NDArray[np.bool_] | None = None) -> EdgeFeatures:
    """:func:`detect_edges` with ``options``, at the training or the test feature budget."""
    low, high = options.thresholds
    budget = options.max_train_features if training else frame_budget(options, image.shape[:2])
    return detect_edges(image, sigma=options.sigma, low_threshold=low, high_threshold=high,
                        spacing=options.spacing, max_points=budget, mask=mask)


def without_box(features: EdgeFeatures, box: tuple[float, float, float, float] | NDArray,
                grow: float = 0.0) -> EdgeFeatures:
    """The features outside a box ``(x, y, w, h)`` grown by ``grow`` of its size on each side."""
    x, y, w, h = (float(b) for b in box)
    x, y, w, h = x - grow * w, y - grow * h, w * (1 + 2 * grow), h * (1 + 2 * grow)
    u, v = features.xy[:, 0], features.xy[:, 1]
    keep = ~((u >= x) & (u <= x + w) & (v >= y) & (v <= y + h))
    return EdgeFeatures(xy=features.xy[keep], theta=features.theta[keep])


def box_mask(shape: tuple[int, int], box: NDArray[np.float64], *, margin: float = 2.0
             ) -> NDArray[np.bool_]:
    """Boolean mask of the pixels inside ``box = (x, y, w, h)`` grown by ``margin``."""
    x, y, w, h = box
    rows = np.arange(shape[0])[:, None]
    cols = np.arange(shape[1])[None, :]
    return ((cols >= x - margin) & (cols <= x + w - 1 + margin)
            & (rows >= y - margin) & (rows <= y + h - 1 + margin))


def normalize_features(features: EdgeFeatures, *, center: NDArray[np.float64], scale: float,
                       inplane: float = 0.0) -> EdgeFeatures:
    """Object-centred, scale-normalised, upright features (Sec. II-A).

    Subtracts the reference point, undoes the view's in-plane rotation and
    divides by its scale, so that the pose's ``w2`` and ``w3`` can be applied
    analytically later.
    """
    xy = rotate_points(features.xy - np.asarray(center, dtype=np.float64), -inplane) / scale
    theta = np.mod(features.theta - inplane, np.pi)
    return EdgeFeatures(xy=xy, theta=theta)
