"""Each training view's outline, for the object's box under any in-plane angle.

Beyond the paper. The bounding box of a view's training box turned by the
pose's in-plane angle bounds the object loosely: turned, a box's corners
reach far past the object. Where training gives masks, each view keeps the
support function of its mask's convex hull (its extent in
:data:`OUTLINE_ANGLES` directions from the reference point, upright), and a
pose's box is the extent of that outline turned, scaled and placed: exact
for the hull at the sampled directions, and the mask's own box at
in-plane 0.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from posevote.geometry import rotate_points
from posevote.model.density import PoseModel, view_average

#: Directions of the support function, evenly from 0 (a multiple of 4, so that
#: the box of an upright pose reads four samples exactly).
OUTLINE_ANGLES = 36


def _angles() -> NDArray[np.float64]:
    return np.arange(OUTLINE_ANGLES, dtype=np.float64) * (2.0 * np.pi / OUTLINE_ANGLES)


def _directions() -> NDArray[np.float64]:
    angles = _angles()
    return np.column_stack([np.cos(angles), np.sin(angles)])


def mask_outline(mask: NDArray[np.bool_], centre: ArrayLike, inplane: float
                 ) -> NDArray[np.float64]:
    """The support function of a mask's convex hull, shape (:data:`OUTLINE_ANGLES`,).

    Parameters
    ----------
    mask : ndarray of bool, shape (H, W)
        The object's pixels (not empty).
    centre : ndarray, shape (2,)
        The reference point, image pixels.
    inplane : float
        The view's in-plane angle, radians; undone, as the features' is.

    Returns
    -------
    ndarray
        The hull's furthest extent from ``centre`` in each direction, pixels;
        pixel ``(r, c)`` covers ``[c, c + 1) x [r, r + 1)``, as boxes do.
    """
    points = cv2.findNonZero(mask.astype(np.uint8))
    if points is None:
        raise ValueError("mask_outline needs a mask with at least one pixel")
    hull = cv2.convexHull(points).reshape(-1, 2).astype(np.float64)
    corners = (hull[:, None, :] + np.array([[0, 0], [1, 0], [0, 1], [1, 1]])).reshape(-1, 2)
    upright = rotate_points(corners - np.asarray(centre, dtype=np.float64), -inplane)
    return np.asarray((upright @ _directions().T).max(axis=0), dtype=np.float64)


def box_outline(size: NDArray[np.float64]) -> NDArray[np.float64]:
    """The support function of a ``(w, h)`` box centred on the reference point."""
    w, h = np.asarray(size, dtype=np.float64)
    d = _directions()
    return np.asarray(np.abs(d[:, 0]) * w / 2.0 + np.abs(d[:, 1]) * h / 2.0, dtype=np.float64)


def outline_box(outline: NDArray[np.float64], position: tuple[float, float], scale: float,
                alpha: float) -> tuple[float, float, float, float]:
    """The box ``(x, y, w, h)`` of an outline turned by ``alpha``, scaled and placed.

    The turned outline's extent along an image axis is the upright outline's
    along that axis turned back, read from the support function by linear
    interpolation between its directions.
    """
    axes = rotate_points(np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]]), -alpha)
    angles = np.arctan2(axes[:, 1], axes[:, 0])
    right, left, down, up = scale * np.interp(angles, _angles(), outline, period=2.0 * np.pi)
    x, y = position
    return float(x - left), float(y - up), float(left + right), float(up + down)


def inside_outline(points: ArrayLike, outline: NDArray[np.float64], position: ArrayLike,
                   scale: float, alpha: float) -> NDArray[np.bool_]:
    """Which image points lie inside an outline turned by ``alpha``, scaled and placed.

    Parameters
    ----------
    points : array_like, shape (N, 2)
        Image points ``(u, v)``.
    outline : ndarray, shape (:data:`OUTLINE_ANGLES`,)
        A support function (:func:`mask_outline`, :func:`outline_at`).
    position : array_like, shape (2,)
        Where the reference point lies, pixels.
    scale, alpha : float
        The pose's scale and in-plane angle (radians).

    Returns
    -------
    ndarray of bool, shape (N,)
        Inside the hull at every sampled direction (the hull's polygon of
        those directions' tangent lines, which contains the hull).
    """
    upright = rotate_points(np.asarray(points, dtype=np.float64).reshape(-1, 2)
                            - np.asarray(position, dtype=np.float64), -alpha) / scale
    return np.asarray(np.all(upright @ _directions().T <= outline, axis=1), dtype=bool)


def outline_at(model: PoseModel, azimuth: float, elevation: float, *, kappa: float,
               k1_cutoff: float) -> NDArray[np.float64] | None:
    """The outline at a viewpoint, reference pixels: the views' ``view_outline`` averaged
    with the pose kernel K1 over the views where it reaches ``k1_cutoff`` (the nearest
    view alone if none), as the box is; None for a model without them."""
    if model.view_outline is None:
        return None
    return view_average(model, model.view_outline, azimuth, elevation, kappa=kappa,
                        k1_cutoff=k1_cutoff)
