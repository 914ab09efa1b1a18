"""Feature morphing between neighbouring training views (beyond the paper).

The paper's density psi blends the features of the training views near a
viewpoint, each feature staying where it was in its own view. Between two
training views no blend of them looks like the object does there: the edges
of a rotating object move, and the blend of two misaligned copies is best
explained at either training view, which pulls estimates toward them and
lets the in-plane angle, scale and position lean toward one neighbour.

Here every training feature also carries where it moves to in each
neighbouring view of the same instance (the view next in azimuth, either
way, at its elevation; over a sphere of views also the view next in
elevation, either way, at its azimuth), measured by dense optical flow
between the two training images (OpenCV's DIS flow). Between views a
feature is moved along those displacements in proportion to the angle
travelled toward each neighbour (:func:`morphed_positions`), so that the
blend at any viewpoint is a plausible picture of the object there.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from posevote.features.edges import EdgeFeatures, normalize_features
from posevote.geometry import angle_difference

#: Neighbouring views farther apart than this (radians) are not morphed into
#: each other: the flow between them would not be trusted.
MAX_GAP = np.radians(45.0)


def view_neighbours(view_azimuth: NDArray[np.float64], view_elevation: NDArray[np.float64],
                    view_instance: NDArray[np.int64], *, max_gap: float = MAX_GAP
                    ) -> NDArray[np.int64]:
    """The next and previous view of each view in azimuth (and, over the sphere, in
    elevation), within its instance.

    Parameters
    ----------
    view_azimuth, view_elevation : ndarray, shape (K,)
        Viewpoints, radians.
    view_instance : ndarray of int, shape (K,)
        Instance of each view.
    max_gap : float, optional
        Neighbours farther apart than this (radians) are not paired.

    Returns
    -------
    ndarray of int, shape (K, 2) or (K, 4)
        Column 0 the next view in azimuth at the view's elevation (its ring),
        column 1 the previous one; where an instance's views lie at several
        elevations, columns 2 and 3 the next and previous view in elevation
        at the view's azimuth. -1 where there is none.
    """
    k = len(view_azimuth)
    az = np.mod(np.asarray(view_azimuth, dtype=np.float64), 2 * np.pi)
    el = np.asarray(view_elevation, dtype=np.float64)
    sphere = any(np.ptp(el[view_instance == i]) > 1e-6 for i in np.unique(view_instance))
    out = np.full((k, 4 if sphere else 2), -1, dtype=np.int64)
    for inst in np.unique(view_instance):
        views = np.flatnonzero(view_instance == inst)
        # A ring shares an elevation and closes; a column shares an azimuth and does not.
        for level in np.unique(np.round(el[views], 6)):
            _pair_along(out, views[np.abs(el[views] - level) < 1e-6], az, (0, 1),
                        closed=True, max_gap=max_gap)
        if sphere:
            for heading in np.unique(np.round(az[views], 6)):
                _pair_along(out, views[np.abs(az[views] - heading) < 1e-6], el, (2, 3),
                            closed=False, max_gap=max_gap)
    return out


def _pair_along(out: NDArray[np.int64], line: NDArray[np.int64], angle: NDArray[np.float64],
                cols: tuple[int, int], *, closed: bool, max_gap: float) -> None:
    """Write into ``out[:, cols]`` each view's next and previous view of ``line`` in
    ``angle`` (a circle when ``closed``), where the gap is at most ``max_gap``."""
    order = line[np.argsort(angle[line], kind="stable")]
    for i, v in enumerate(order):
        for col, step in zip(cols, (1, -1), strict=True):
            j = i + step
            if not (closed or 0 <= j < len(order)):
                continue
            n = order[j % len(order)]
            gap = abs(float(angle_difference(angle[n], angle[v]) if closed
                            else angle[n] - angle[v]))
            if n != v and 1e-9 < gap <= max_gap:
                out[v, col] = n


def _window(box: NDArray[np.float64], shape: tuple[int, int], margin: float
            ) -> tuple[int, int, int, int]:
    x, y, w, h = box
    x0 = int(max(np.floor(x - margin * w), 0))
    y0 = int(max(np.floor(y - margin * h), 0))
    x1 = int(min(np.ceil(x + w + margin * w), shape[1]))
    y1 = int(min(np.ceil(y + h + margin * h), shape[0]))
    return x0, y0, x1, y1


class ViewCrops:
    """Grey crops of the training views around their boxes, for the flow.

    Parameters
    ----------
    margin : float, optional
        Each crop is the box grown by this fraction of its size on every side.
    """

    def __init__(self, margin: float = 0.5) -> None:
        self.margin = margin
        self.crops: list[NDArray[np.uint8]] = []
        self.origins: list[tuple[int, int]] = []

    def add(self, image: NDArray[np.float64], box: NDArray[np.float64]) -> None:
        """Keep the crop of one view (image in [0, 1], box ``(x, y, w, h)``)."""
        x0, y0, x1, y1 = _window(np.asarray(box, dtype=np.float64), image.shape, self.margin)
        self.crops.append(np.round(np.clip(image[y0:y1, x0:x1], 0, 1) * 255).astype(np.uint8))
        self.origins.append((x0, y0))

    def flow(self, a: int, b: int) -> tuple[NDArray[np.float32], tuple[int, int]]:
        """Dense flow from view ``a`` to view ``b`` on a canvas holding both crops.

        Returns the flow, shape (H, W, 2), and the canvas origin in image pixels.
        """
        (ax, ay), (bx, by) = self.origins[a], self.origins[b]
        ca, cb = self.crops[a], self.crops[b]
        x0, y0 = min(ax, bx), min(ay, by)
        x1 = max(ax + ca.shape[1], bx + cb.shape[1])
        y1 = max(ay + ca.shape[0], by + cb.shape[0])
        canvas_a = np.zeros((y1 - y0, x1 - x0), dtype=np.uint8)
        canvas_b = np.zeros_like(canvas_a)
        canvas_a[ay - y0:ay - y0 + ca.shape[0], ax - x0:ax - x0 + ca.shape[1]] = ca
        canvas_b[by - y0:by - y0 + cb.shape[0], bx - x0:bx - x0 + cb.shape[1]] = cb
        dis = cv2.DISOpticalFlow_create(  # type: ignore[attr-defined]
            cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
        return dis.calc(canvas_a, canvas_b, None), (x0, y0)


def _sample(flow: NDArray[np.float32], xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """The flow at sub-pixel positions (bilinear, clamped at the border)."""
    xs = np.ascontiguousarray(xy[:, :1], dtype=np.float32)
    ys = np.ascontiguousarray(xy[:, 1:], dtype=np.float32)
    return cv2.remap(flow, xs, ys, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE).reshape(-1, 2).astype(np.float64)


def view_shifts(view_features: Sequence[EdgeFeatures], crops: ViewCrops,
                neighbours: NDArray[np.int64], *, centers: NDArray[np.float64],
                scales: NDArray[np.float64], inplanes: NDArray[np.float64]
                ) -> NDArray[np.float64]:
    """Where each training feature moves to in each of its view's neighbours.

    Parameters
    ----------
    view_features : sequence of EdgeFeatures
        Each view's features in image pixels (as given to
        :func:`posevote.model.density.build_model`, in the same order).
    crops : ViewCrops
        The views' crops, in the same order.
    neighbours : ndarray of int, shape (K, C)
        From :func:`view_neighbours`.
    centers, scales, inplanes
        Each view's reference point, scale and in-plane angle, as for
        :func:`posevote.model.density.build_model`.

    Returns
    -------
    ndarray, shape (M, C, 2)
        For every model feature (views concatenated in order), its
        displacement in model units toward each neighbour (``[:, c]`` toward
        ``neighbours[:, c]``); zero where a view has no neighbour.
    """
    out = []
    for k, feats in enumerate(view_features):
        here = normalize_features(feats, center=centers[k], scale=float(scales[k]),
                                  inplane=float(inplanes[k])).xy
        shift = np.zeros((len(feats), neighbours.shape[1], 2))
        for col in range(neighbours.shape[1]):
            n = int(neighbours[k, col])
            if n < 0 or len(feats) == 0:
                continue
            flow, origin = crops.flow(k, n)
            moved = feats.xy + _sample(flow, feats.xy - np.asarray(origin, dtype=np.float64))
            there = normalize_features(EdgeFeatures(xy=moved, theta=feats.theta),
                                       center=centers[n], scale=float(scales[n]),
                                       inplane=float(inplanes[n])).xy
            shift[:, col] = there - here
        out.append(shift)
    return np.concatenate(out) if out else np.zeros((0, neighbours.shape[1], 2))


def morphed_positions(xy: NDArray[np.float64], shift: NDArray[np.float64],
                      view: NDArray[np.int64], azimuth: float,
                      view_azimuth: NDArray[np.float64], neighbours: NDArray[np.int64], *,
                      elevation: float = 0.0,
                      view_elevation: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """Feature positions moved toward the viewpoint ``(azimuth, elevation)``.

    A feature of view ``k`` at ``azimuth`` between ``k`` and its neighbour
    ``n`` moves by the fraction ``(azimuth - az_k) / (az_n - az_k)`` (at most
    1) of its displacement toward ``n``; over the sphere it also moves so
    toward its neighbour in elevation (the two moves add: a first-order
    picture of the object between four views).

    Parameters
    ----------
    xy : ndarray, shape (N, 2)
        Model positions of the features.
    shift : ndarray, shape (N, C, 2)
        Their displacements (:func:`view_shifts`).
    view : ndarray of int, shape (N,)
        Their views.
    azimuth : float
        The viewpoint's azimuth, radians.
    view_azimuth : ndarray, shape (K,)
        Azimuth of every view.
    neighbours : ndarray of int, shape (K, C)
        From :func:`view_neighbours`.
    elevation : float, optional
        The viewpoint's elevation, radians (read where ``C`` is 4).
    view_elevation : ndarray, shape (K,), optional
        Elevation of every view (needed where ``C`` is 4).

    Returns
    -------
    ndarray, shape (N, 2)
    """
    rows = np.arange(len(view))
    moves = [(angle_difference(azimuth, view_azimuth[view]), view_azimuth, 0, True)]
    if neighbours.shape[1] == 4:
        if view_elevation is None:
            raise ValueError("a model morphed over the sphere needs view_elevation")
        moves.append((elevation - view_elevation[view], view_elevation, 2, False))
    out = np.array(xy, dtype=np.float64, copy=True)
    for delta, angles, first, ring in moves:
        col = np.where(delta >= 0, first, first + 1)
        n = neighbours[view, col]
        there = angles[np.maximum(n, 0)]
        gap = np.abs(angle_difference(there, angles[view]) if ring else there - angles[view])
        frac = np.where(n >= 0, np.clip(np.abs(delta) / np.maximum(gap, 1e-12), 0.0, 1.0), 0.0)
        out += frac[:, None] * shift[rows, col]
    return out
