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
                      position_sigma: float, orientation_kappa: float, viewpoint_kappa: float,
                      block_cells: int = 20_000_000) -> NDArray[np.float64]:
    """Eq. 4 over the views of one instance (``view`` indexes ``directions``).

    The strongest response per feature and view is gathered in a table of
    features x views, a block of views at a time so that a block holds at
    most ``block_cells`` cells (20 million: a table of 160 MB, and its
    weighting's temporaries about as much again, however many views).
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
    k1_views = viewpoint_kernel(directions[:, None, :], directions[None, :, :], viewpoint_kappa)
    theta = np.ascontiguousarray(theta, dtype=np.float64)
    view = np.ascontiguousarray(view, dtype=np.int64)
    block = max(1, block_cells // m)
    ambiguity = np.zeros(m)
    for lo in range(0, k_views, block):
        hi = min(k_views, lo + block)
        # psi~_k(x_i) for every feature and the block's views: the strongest
        # response among the features of view k (0 where none is near). The
        # strongest response is the exponential of the largest exponent: one
        # exponential per table cell instead of one per pair.
        psi = np.full((m, hi - lo), -np.inf)
        _strongest_exponents(xy, theta, view, cells, order, start, n_rows, n_cols,
                             float(radius), float(position_sigma), float(orientation_kappa),
                             lo, hi, psi)
        np.exp(psi, out=psi)
        ambiguity += np.einsum("ik,ik->i", psi, 1.0 - k1_views[view, lo:hi])
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
def _strongest_exponents(xy, theta, view, cells, order, start, n_rows, n_cols, radius, sigma,
                         kappa, v_lo, v_hi, out):  # pragma: no cover - compiled
    """``out[i, k - v_lo]``: the log of the strongest kernel response at feature i of any
    feature of view k within ``radius``, for the views ``v_lo <= k < v_hi`` (``out``
    starts at -inf).

    The features are sorted into square cells at least ``radius`` wide (``cells``
    holds each one's column and row on an ``n_rows`` x ``n_cols`` grid, keyed
    ``row * n_cols + col``; ``order`` sorts the features by key and
    ``start[key]`` is where a key's run begins): each feature meets
    the later features of its own cell and those of the four cells after it
    in row-major order among its eight neighbours, so each pair once. A
    feature's response to itself is 1.
    """
    for a in range(xy.shape[0]):
        if v_lo <= view[a] < v_hi:
            out[a, view[a] - v_lo] = 0.0
    inv = 1.0 / (2.0 * sigma * sigma)
    r2 = radius * radius
    for pa in range(order.shape[0]):
        a = order[pa]
        col = cells[a, 0]
        row = cells[a, 1]
        for dr, dc in ((0, 0), (0, 1), (1, -1), (1, 0), (1, 1)):
            rr = row + dr
            cc = col + dc
            if rr >= n_rows or cc < 0 or cc >= n_cols:
                continue
            key = rr * n_cols + cc
            lo = start[key]
            hi = start[key + 1]
            if dr == 0 and dc == 0:
                lo = pa + 1
            for pb in range(lo, hi):
                b = order[pb]
                dx = xy[a, 0] - xy[b, 0]
                dy = xy[a, 1] - xy[b, 1]
                d2 = dx * dx + dy * dy
                if d2 > r2:
                    continue
                a_in = v_lo <= view[a] < v_hi
                b_in = v_lo <= view[b] < v_hi
                if not (a_in or b_in):
                    continue
                # Both kernels' exponents summed.
                r = kappa * (np.cos(2.0 * (theta[a] - theta[b])) - 1.0) - d2 * inv
                if b_in and r > out[a, view[b] - v_lo]:
                    out[a, view[b] - v_lo] = r
                if a_in and r > out[b, view[a] - v_lo]:
                    out[b, view[a] - v_lo] = r
