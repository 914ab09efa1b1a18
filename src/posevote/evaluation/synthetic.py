"""Test images with clutter and occlusion, made from views on a plain background.

Used by the embedded demo and the cluttered COIL benchmark: an object view is
pasted at a random position, scale and in-plane rotation onto a crop of one of
scikit-image's bundled sample photographs, and part of it is hidden behind a
patch of another photograph.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import cv2
import numpy as np
from numpy.typing import NDArray

from posevote.data.images import as_gray_float
from posevote.data.training_set import object_mask
from posevote.geometry import box_centre

_BACKGROUNDS = ("astronaut", "camera", "coffee", "chelsea", "rocket", "brick", "grass", "gravel",
                "coins", "moon", "clock", "immunohistochemistry")


@dataclass(frozen=True, kw_only=True, eq=False)
class PastedView:
    """A synthetic test image and its truth.

    Attributes
    ----------
    image : ndarray, shape (H, W)
        Grey image in [0, 1].
    position : (float, float)
        Where the view's reference point (its box centre) landed, pixels.
    scale : float
        Applied scale.
    inplane : float
        Applied in-plane rotation, radians (library convention).
    box : (float, float, float, float)
        Box of the visible-or-occluded object, pixels.
    occluded_fraction : float
        Fraction of the object's pixels hidden.
    """

    image: NDArray[np.float64]
    position: tuple[float, float]
    scale: float
    inplane: float
    box: tuple[float, float, float, float]
    occluded_fraction: float


@cache
def _background(name: str) -> NDArray[np.float64]:
    import skimage.data

    return as_gray_float(np.asarray(getattr(skimage.data, name)()), name=name)


def bundled_photographs() -> tuple[NDArray[np.float64], ...]:
    """The bundled scikit-image photographs that the clutter is cut from (no cars in them)."""
    return tuple(_background(name) for name in _BACKGROUNDS)


def clutter_background(shape: tuple[int, int], *, rng: np.random.Generator) -> NDArray[np.float64]:
    """A random crop of a bundled scikit-image photograph, resized to ``shape``."""
    src = _background(_BACKGROUNDS[rng.integers(len(_BACKGROUNDS))])
    h, w = src.shape
    side = int(rng.integers(min(h, w) // 2, min(h, w) + 1))
    r = int(rng.integers(0, h - side + 1))
    c = int(rng.integers(0, w - side + 1))
    crop = src[r:r + side, c:c + side]
    return np.asarray(cv2.resize(crop, (shape[1], shape[0]), interpolation=cv2.INTER_AREA),
                      dtype=np.float64)


def paste_on_clutter(view: NDArray, box: NDArray[np.float64], *, rng: np.random.Generator,
                     canvas_shape: tuple[int, int] = (256, 256),
                     scale_range: tuple[float, float] = (0.7, 1.3),
                     inplane_range_deg: tuple[float, float] = (-30.0, 30.0),
                     occlusion: float = 0.2, mask: NDArray[np.bool_] | None = None,
                     backdrop: Callable[..., NDArray[np.float64]] | None = None) -> PastedView:
    """Paste an object view onto clutter, with a random similarity transform.

    Parameters
    ----------
    view : ndarray
        The object on a dark background (or with ``mask``).
    box : ndarray, shape (4,)
        The view's object box ``(x, y, w, h)``; its centre is the reference
        point whose new position is returned.
    rng : numpy.random.Generator
        Source of randomness.
    canvas_shape : (int, int), optional
        Output size (H, W).
    scale_range, inplane_range_deg : (float, float), optional
        Ranges of the random scale and in-plane rotation.
    occlusion : float, optional
        Fraction of the object's pixels to hide (a band from a random side).
    mask : ndarray of bool, optional
        The object's pixels (default: :func:`posevote.data.object_mask`).
    backdrop : callable, optional
        ``backdrop(shape, rng=rng)``: the background and the occluder's patch
        (default: :func:`clutter_background`).

    Returns
    -------
    PastedView
    """
    img = as_gray_float(view)
    obj_mask = (object_mask(img) if mask is None else mask).astype(np.float32)
    scale = float(rng.uniform(*scale_range))
    alpha = float(np.radians(rng.uniform(*inplane_range_deg)))
    x, y, w, h = box
    centre = np.asarray(box_centre(box), dtype=np.float64)
    rot = scale * np.array([[np.cos(alpha), -np.sin(alpha)], [np.sin(alpha), np.cos(alpha)]])
    corners = (np.array([[x, y], [x + w, y], [x, y + h], [x + w, y + h]]) - centre) @ rot.T
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    H, W = canvas_shape
    u = float(rng.uniform(-lo[0] + 2, W - hi[0] - 2)) if W - hi[0] - 2 > -lo[0] + 2 else W / 2
    v = float(rng.uniform(-lo[1] + 2, H - hi[1] - 2)) if H - hi[1] - 2 > -lo[1] + 2 else H / 2
    M = np.hstack([rot, (np.array([u, v]) - rot @ centre)[:, None]])
    warped = cv2.warpAffine(img.astype(np.float32), M, (W, H), flags=cv2.INTER_LINEAR)
    warped_mask = cv2.warpAffine(obj_mask, M, (W, H), flags=cv2.INTER_LINEAR)
    backdrop = clutter_background if backdrop is None else backdrop
    background = backdrop(canvas_shape, rng=rng)
    out = warped_mask * warped + (1.0 - warped_mask) * background
    hidden = 0.0
    inside = warped_mask > 0.5
    if occlusion > 0 and inside.any():
        side = int(rng.integers(4))
        rows, cols = np.nonzero(inside)
        coord = (cols, -cols, rows, -rows)[side]
        cut = np.quantile(coord, occlusion)
        band = np.zeros_like(inside)
        sel = coord <= cut
        r0, r1, c0, c1 = rows[sel].min(), rows[sel].max(), cols[sel].min(), cols[sel].max()
        if side < 2:
            band[rows.min():rows.max() + 1, c0:c1 + 1] = True
        else:
            band[r0:r1 + 1, cols.min():cols.max() + 1] = True
        occluder = backdrop(canvas_shape, rng=rng)
        out = np.where(band, occluder, out)
        hidden = float((band & inside).sum() / inside.sum())
    rows, cols = np.nonzero(inside)
    obj_box = (float(cols.min()), float(rows.min()), float(np.ptp(cols) + 1), float(np.ptp(rows) + 1)
               ) if rows.size else (u, v, 0.0, 0.0)
    return PastedView(image=np.clip(out, 0.0, 1.0).astype(np.float64), position=(u, v), scale=scale,
                      inplane=alpha, box=obj_box, occluded_fraction=hidden)
