"""Pose-specificity weights of training features (Sec. II-C, Eq. 4).

Our reading of Eq. 4 (METHOD.md)::

    wt(w_i, x_i) = 1 - 1/K * sum_k psi~_k(x_i) * (1 - K1~(w_i, w_k))

``psi~_k(x)`` is the max-normalised appearance density of training view
``k`` at ``x`` (here: the strongest kernel response of any feature of view
``k``, in ``[0, 1]``), and ``K1~`` the max-normalised pose kernel. A feature
that also shows up, at the same object-centred place and orientation, in
views of very different pose gets a low weight; one that pins the pose down
gets a weight near 1.

The sum runs over the views of the feature's own instance: in a category
model, a feature is ambiguous when its own object shows it in very
different poses (the cost then grows linearly with the number of
instances, not quadratically).
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from posevote._parallel import thread_map
from posevote.model.density import PoseModel
from posevote.model.kernels import orientation_kernel, position_kernel, viewpoint_kernel


def feature_weights(model: PoseModel, *, position_sigma: float, orientation_kappa: float,
                    viewpoint_kappa: float, n_threads: int = 1) -> NDArray[np.float64]:
    """Weights ``wt_i`` of Eq. 4 for every training feature.

    Parameters
    ----------
    model : PoseModel
        The training pairs (their current weights are ignored).
    position_sigma : float
        Width of the appearance kernel in position, reference pixels.
    orientation_kappa : float
        Concentration of the appearance kernel in orientation.
    viewpoint_kappa : float
        Concentration of the pose kernel K1 on viewing directions.
    n_threads : int, optional
        Instances weighed at once (each on its own: the same weights).

    Returns
    -------
    ndarray, shape (M,)
        Weights in ``[0, 1]``.
    """
    weights = np.zeros(model.n_features)
    directions = model.view_directions()

    def weigh(inst: int) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        views = np.flatnonzero(model.view_instance == inst)
        local = np.full(model.n_views, -1, dtype=np.int64)
        local[views] = np.arange(len(views))
        idx = np.flatnonzero(local[model.view] >= 0)
        return idx, _instance_weights(model.xy[idx], model.theta[idx], local[model.view[idx]],
                                      directions[views], position_sigma=position_sigma,
                                      orientation_kappa=orientation_kappa,
                                      viewpoint_kappa=viewpoint_kappa)

    for idx, values in thread_map(weigh, np.unique(model.view_instance).tolist(), n_threads,
                                  ahead=1):
        weights[idx] = values
    return weights


_MAX_CELLS_PER_SIDE = 1024
#: A feature's appearance kernel reaches this many position sigmas.
_REACH_SIGMAS = 3.0


def _instance_weights(xy: NDArray[np.float64], theta: NDArray[np.float64],
                      view: NDArray[np.int64], directions: NDArray[np.float64], *,
                      position_sigma: float, orientation_kappa: float,
                      viewpoint_kappa: float) -> NDArray[np.float64]:
    """Eq. 4 over the views of one instance (``view`` indexes ``directions``).

    Each feature's strongest response per view is gathered for that feature
    alone (:func:`_ambiguity`): the time grows with the pairs within reach,
    the memory with the views, never with features x views.
    """
    m, k_views = len(theta), len(directions)
    if m == 0:
        return np.zeros(0)
    radius = _REACH_SIGMAS * position_sigma
    # The pairs within reach are visited on a grid of cells, never listed.
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    # Cells at least the reach wide, and at most MAX_CELLS_PER_SIDE of them a side
    # (a tiny kernel over a wide model would otherwise ask for billions).
    low = xy.min(axis=0)
    side = max(radius, float(np.max(xy.max(axis=0) - low)) / _MAX_CELLS_PER_SIDE)
    cells = np.floor((xy - low) / side).astype(np.int64)
    n_cols, n_rows = (int(n) + 1 for n in cells.max(axis=0))
    key = cells[:, 1] * n_cols + cells[:, 0]
    order = np.argsort(key, kind="stable")
    start = np.searchsorted(key[order], np.arange(n_rows * n_cols + 1))
    unlike = 1.0 - viewpoint_kernel(directions[:, None, :], directions[None, :, :],
                                    viewpoint_kappa)
    ambiguity = _ambiguity(xy, np.ascontiguousarray(theta, dtype=np.float64),
                           np.ascontiguousarray(view, dtype=np.int64), cells, order, start,
                           n_rows, n_cols, float(radius), float(position_sigma),
                           float(orientation_kappa), np.ascontiguousarray(unlike))
    return np.clip(1.0 - ambiguity / k_views, 0.0, 1.0)


def instance_weights_reference(xy: NDArray[np.float64], theta: NDArray[np.float64],
                               view: NDArray[np.int64], directions: NDArray[np.float64], *,
                               position_sigma: float, orientation_kappa: float,
                               viewpoint_kappa: float) -> NDArray[np.float64]:
    """Pure-numpy :func:`_instance_weights` (for tests): every pair within reach listed,
    both ways, plus each feature with itself."""
    # imported where used, so that a command-line start does not pay for it
    from scipy.spatial import cKDTree

    m, k_views = len(theta), len(directions)
    pairs = cKDTree(xy).query_pairs(_REACH_SIGMAS * position_sigma, output_type="ndarray")
    i = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(m)])
    j = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(m)])
    d2 = np.sum((xy[i] - xy[j]) ** 2, axis=1)
    response = position_kernel(d2, position_sigma) * orientation_kernel(
        theta[i] - theta[j], orientation_kappa)
    # psi~_k(x_i): strongest response among the features of view k.
    key = i * k_views + view[j]
    order = np.lexsort((-response, key))
    key, response, i = key[order], response[order], i[order]
    first = np.ones(len(key), dtype=bool)
    first[1:] = key[1:] != key[:-1]
    i, view_k, psi = i[first], key[first] % k_views, response[first]
    k1 = viewpoint_kernel(directions[view[i]], directions[view_k], viewpoint_kappa)
    ambiguity = np.bincount(i, weights=psi * (1.0 - k1), minlength=m) / k_views
    return np.clip(1.0 - ambiguity, 0.0, 1.0)


@numba.njit(cache=True, nogil=True)
def _ambiguity(xy, theta, view, cells, order, start, n_rows, n_cols, radius, sigma, kappa,
               unlike):  # pragma: no cover - compiled
    """``sum_k psi~_k(x_i) (1 - K1~(w_i, w_k))`` for every feature ``i``: ``psi~_k(x_i)`` the
    strongest kernel response at feature ``i`` of any feature of view ``k`` within
    ``radius`` (a feature's response to itself is 1), ``unlike[i, k]`` the ``1 - K1~`` of
    two views.

    The features are sorted into square cells at least ``radius`` wide (``cells``
    holds each one's column and row on an ``n_rows`` x ``n_cols`` grid, keyed
    ``row * n_cols + col``; ``order`` sorts the features by key and
    ``start[key]`` is where a key's run begins): each feature meets the
    features of its own cell and its eight neighbours. Its strongest exponent
    per view is kept in one row over the views, and only the views it met are
    summed and reset.
    """
    m = xy.shape[0]
    k_views = unlike.shape[0]
    inv = 1.0 / (2.0 * sigma * sigma)
    r2 = radius * radius
    best = np.full(k_views, -np.inf)
    met = np.empty(k_views, dtype=np.int64)
    out = np.zeros(m)
    for a in range(m):
        col = cells[a, 0]
        row = cells[a, 1]
        n_met = 1
        met[0] = view[a]
        best[view[a]] = 0.0
        for dr in (-1, 0, 1):
            rr = row + dr
            if rr < 0 or rr >= n_rows:
                continue
            for dc in (-1, 0, 1):
                cc = col + dc
                if cc < 0 or cc >= n_cols:
                    continue
                key = rr * n_cols + cc
                for pb in range(start[key], start[key + 1]):
                    b = order[pb]
                    if b == a:
                        continue
                    dx = xy[a, 0] - xy[b, 0]
                    dy = xy[a, 1] - xy[b, 1]
                    d2 = dx * dx + dy * dy
                    if d2 > r2:
                        continue
                    # Both kernels' exponents summed.
                    r = kappa * (np.cos(2.0 * (theta[a] - theta[b])) - 1.0) - d2 * inv
                    k = view[b]
                    if best[k] == -np.inf:
                        met[n_met] = k
                        n_met += 1
                    if r > best[k]:
                        best[k] = r
        # The views in increasing order, as a sum over the whole row would take them.
        seen = np.sort(met[:n_met])
        total = 0.0
        for t in range(n_met):
            k = seen[t]
            total += np.exp(best[k]) * unlike[view[a], k]
            best[k] = -np.inf
        out[a] = total
    return out
