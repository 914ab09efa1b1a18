"""How alike each training view is to the object's other sides (beyond the paper).

A ring, a plain pot or a bottle shows the same outline from every side: its
edges do not define its azimuth, and the probability of a pose read from
them (a share of the score profile, calibrated over many objects) does not
know it, since one side still scores a little over the others in every
image. The model knows it at training: :func:`view_lookalikes` gives each
view the share of its edges that the most alike view of another side explains
and the share of that view's it explains, averaged; another side is a view of
the same instance at least the angle within which a pose counts as right
away (:data:`~posevote.geometry.MODE_RADIUS`). An estimate at a
view alike to another side by :data:`posevote.results.LOOKALIKE` or more is
ambiguous (:attr:`posevote.results.PoseEstimate.ambiguous`): its azimuth may
as well be that side's. :class:`LookalikeCollector` lays the measure on the model
when it is fitted (what the estimate's ``lookalike`` step needs), at the
default kernel's width, where :data:`~posevote.results.LOOKALIKE` was chosen.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from posevote.features.edges import EdgeFeatures
from posevote.geometry import MODE_RADIUS, viewing_direction
from posevote.model.density import PoseModel
from posevote.model.kernels import ORIENTATION_KAPPA, KernelOptions
from posevote.scoring.maps import TestMaps, prepare_test
from posevote.scoring.score import density_at, phi_at, place_features

#: The most views of one instance each view is compared with (evenly spaced among its
#: views where it has more): by hand, so that the time grows with the views, not with their
#: square (468 views over the sphere: every pair, about 3 s).
MAX_SIDES = 600


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
        (:data:`~posevote.geometry.MODE_RADIUS`; at most
        :data:`MAX_SIDES` of them), the largest mean of the two shares each explains of
        the other (0 where there is none).
    """
    k = len(azimuth)
    alike = np.zeros(k)
    if not len(xy):
        return alike
    # The views' frame moved into an image that holds every view with the kernel's reach.
    margin = 4.0 * position_sigma
    placed = xy - xy.min(axis=0) + margin
    shape = (int(np.ceil(placed[:, 1].max() + margin)), int(np.ceil(placed[:, 0].max() + margin)))
    order = np.argsort(view, kind="stable")
    bounds = np.searchsorted(view[order], np.arange(k + 1))
    members = [order[bounds[v]:bounds[v + 1]] for v in range(k)]
    counts = np.maximum(np.diff(bounds), 1)

    def view_map(v: int) -> TestMaps:
        return prepare_test(EdgeFeatures(xy=placed[members[v]], theta=theta[members[v]]), shape,
                            position_sigma=position_sigma, orientation_kappa=ORIENTATION_KAPPA)

    # Two passes, one view's maps at a time: the maps of every view at once would not fit.
    own = np.zeros(len(xy))
    for v in range(k):
        own[members[v]] = density_at(view_map(v), placed[members[v]], theta[members[v]])

    # Every view's maps share one grid: the points placed on it (and their orientation bins)
    # once.
    grid = view_map(int(view[0]))
    px, py, ofrac = np.empty(len(xy)), np.empty(len(xy)), np.empty(len(xy))
    obins = np.empty((len(xy), 2), dtype=np.int64)
    place_features(grid.frame, grid.density.shape[0], placed, theta, 0.0, 1.0, 0.0, 0.0,
                   px, py, obins, ofrac)

    def shares(maps: TestMaps, views: NDArray[np.int64], out: NDArray[np.float64]) -> None:
        # out[s] = the mean share of views[s]'s edges the maps explain.
        rows = np.concatenate([members[v] for v in views])
        slots = np.repeat(np.arange(len(views)), [len(members[v]) for v in views])
        _explained_shares(maps.density, maps.frame, px, py, obins, ofrac, own, rows, slots, out)
        out /= counts[views]

    directions = viewing_direction(np.asarray(azimuth), np.asarray(elevation))
    for group in np.unique(instance):
        views = np.flatnonzero(instance == group)
        sides = views if len(views) <= MAX_SIDES else views[np.unique(np.rint(
            np.linspace(0, len(views) - 1, MAX_SIDES)).astype(np.int64))]
        apart = directions[views] @ directions[sides].T <= math.cos(MODE_RADIUS) + 1e-9
        if not apart.any():
            continue
        by = np.zeros(apart.shape)                      # views' edges the sides explain
        for b in np.flatnonzero(apart.any(axis=0)):
            column = np.zeros(int(apart[:, b].sum()))
            shares(view_map(int(sides[b])), views[apart[:, b]], column)
            by[apart[:, b], b] = column
        if sides is views:
            of = by.T                                   # the sides' edges the views explain
        else:
            of = np.zeros(apart.shape)
            for a in np.flatnonzero(apart.any(axis=1)):
                row = np.zeros(int(apart[a].sum()))
                shares(view_map(int(views[a])), sides[apart[a]], row)
                of[a, apart[a]] = row
        alike[views] = np.where(apart, 0.5 * (by + of), 0.0).max(axis=1)
    return alike


class LookalikeCollector:
    """Lays :func:`view_lookalikes` on the pooled model while ``fit`` pools the views (a
    :class:`~posevote.model.training.ViewCollector` that reads nothing from the images:
    the model's edges are all it needs, those of earlier views included)."""

    def __init__(self, boxes: NDArray[np.float64]) -> None:
        del boxes

    def read(self, image: NDArray[np.float64], box: NDArray[np.float64],
             mask: NDArray[np.bool_] | None, pose: NDArray[np.float64]) -> None:
        """Nothing from the image."""

    def add(self, index: int, read: Any, box: NDArray[np.float64],
            pose: NDArray[np.float64]) -> None:
        """Nothing to keep."""

    def with_earlier(self, full: PoseModel, size: NDArray[np.float64]) -> None:
        """Nothing: the pooled model holds the earlier views' edges."""

    def onto_model(self, model: PoseModel, scales: NDArray[np.float64]) -> PoseModel:
        """The model with each view's likeness to another side."""
        return replace(model, view_lookalike=view_lookalikes(
            model.xy, model.theta, model.view, model.view_azimuth, model.view_elevation,
            model.view_instance, position_sigma=KernelOptions().position_sigma))

    def learnt(self, sizes: NDArray[np.float64], n_threads: int) -> dict[str, object]:
        """Nothing apart from the model."""
        return {}


@numba.njit(cache=True, nogil=True)
def _explained_shares(density, frame, px, py, obins, ofrac, own, rows, slots, out
                      ):  # pragma: no cover - compiled
    """Add to ``out[slots[r]]``, for each point ``rows[r]`` (placed on the grid by
    :func:`~posevote.scoring.score.place_features`), its density on the maps over ``own``,
    at most 1."""
    for r in range(rows.shape[0]):
        i = rows[r]
        if px[i] < frame[0] or py[i] < frame[1] or px[i] >= frame[2] or py[i] >= frame[3]:
            continue
        phi = phi_at(density, px[i], py[i], obins[i, 0], obins[i, 1], ofrac[i])
        out[slots[r]] += min(1.0, phi / max(own[i], 1e-12))
