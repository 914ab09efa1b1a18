"""How alike each training view is to the object's other sides (beyond the paper).

A ring, a plain pot or a bottle shows the same outline from every side: its
edges do not define its azimuth, and the probability of a pose read from
them (a share of the score profile, calibrated over many objects) does not
know it, since one side still scores a little over the others in every
image. The model knows it at training: :func:`view_lookalikes` gives each
view the share of its edges that the most alike view of another side explains
and the share of that view's it explains, averaged; another side is a view of
the same instance at least the angle within which a pose counts as right
away (:data:`~posevote.refinement.probability.MODE_RADIUS`). An estimate at a
view alike to another side by :data:`posevote.results.LOOKALIKE` or more is
ambiguous (:attr:`posevote.results.PoseEstimate.ambiguous`): its azimuth may
as well be that side's.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from posevote.features.edges import EdgeFeatures
from posevote.geometry import viewing_direction
from posevote.model.kernels import ORIENTATION_KAPPA
from posevote.refinement.probability import MODE_RADIUS
from posevote.scoring.maps import TestMaps, prepare_test
from posevote.scoring.score import density_at, phi_at


def view_lookalikes(xy: NDArray[np.float64], theta: NDArray[np.float64],
                    view: NDArray[np.int64], azimuth: NDArray[np.float64],
                    elevation: NDArray[np.float64], instance: NDArray[np.int64], *,
                    position_sigma: float) -> NDArray[np.float64]:
    """Each view's likeness to the most alike view of another side of its instance.

    The share of a view's edges that another view explains: each edge's
    density of the other view's edges (Eq. 2, as the test image's is read:
    :func:`~posevote.scoring.maps.prepare_test`) over its density of its own
    view's, at most 1, averaged over the view's edges.

    Parameters
    ----------
    xy, theta, view : ndarray
        The model's features (normalised positions, orientations) and their views.
    azimuth, elevation, instance : ndarray, shape (K,)
        Each view's viewpoint (radians) and instance.
    position_sigma : float
        The position kernel's width (reference pixels).

    Returns
    -------
    ndarray, shape (K,)
        In [0, 1]: over the views of the same instance 30 degrees or more away
        (:data:`~posevote.refinement.probability.MODE_RADIUS`), the largest mean of the
        two shares each explains of the other (0 where there is none).
    """
    k = len(azimuth)
    if not len(xy):
        return np.zeros(k)
    # The views' frame moved into an image that holds every view with the kernel's reach.
    margin = 4.0 * position_sigma
    placed = xy - xy.min(axis=0) + margin
    shape = (int(np.ceil(placed[:, 1].max() + margin)), int(np.ceil(placed[:, 0].max() + margin)))

    def view_map(j: int) -> TestMaps:
        mine = view == j
        return prepare_test(EdgeFeatures(xy=placed[mine], theta=theta[mine]), shape,
                            position_sigma=position_sigma, orientation_kappa=ORIENTATION_KAPPA)

    # Two passes, one view's maps at a time: the maps of every view at once would not fit.
    own = np.zeros(len(xy))
    for j in range(k):
        mine = view == j
        own[mine] = density_at(view_map(j), placed[mine], theta[mine])
    directions = viewing_direction(np.asarray(azimuth), np.asarray(elevation))
    apart = directions @ directions.T <= math.cos(MODE_RADIUS) + 1e-9
    apart &= np.asarray(instance)[:, None] == np.asarray(instance)[None, :]
    explained = np.zeros((k, k))
    counts = np.maximum(np.bincount(view, minlength=k), 1)
    for j in range(k):
        if apart[:, j].any():
            maps = view_map(j)
            _explained_shares(maps.density, maps.frame, placed, theta, own, view,
                              apart[:, j], explained[:, j])
    explained /= counts[:, None]
    both = np.where(apart, 0.5 * (explained + explained.T), 0.0)
    return np.asarray(both.max(axis=1), dtype=np.float64)


@numba.njit(cache=True, nogil=True)
def _explained_shares(density, frame, xy, theta, own, view, counted, out
                      ):  # pragma: no cover - compiled
    """Add to ``out[v]``, for each point of a ``counted`` view ``v``, its density on the maps
    over ``own``, at most 1 (as :func:`~posevote.scoring.score.density_at` reads them)."""
    n_bins = density.shape[0]
    bin_width = np.pi / n_bins
    inv = frame[5]
    for i in range(xy.shape[0]):
        if not counted[view[i]]:
            continue
        x = (xy[i, 0] - frame[4]) * inv
        y = (xy[i, 1] - frame[6]) * inv
        if x < frame[0] or y < frame[1] or x >= frame[2] or y >= frame[3]:
            continue
        th = theta[i] - np.pi * np.floor(theta[i] / np.pi)
        f = th / bin_width - 0.5
        fb = np.floor(f)
        b0 = int(fb)
        if b0 < 0:
            b0 += n_bins
        b1 = b0 + 1 if b0 + 1 < n_bins else 0
        out[view[i]] += min(1.0, phi_at(density, x, y, b0, b1, f - fb) / max(own[i], 1e-12))
