"""Translation voting for one pose (Fig. 2), as small kernels.

For a fixed viewpoint ``w1`` and in-plane/scale step ``w2``, the training
features near ``w1`` are moved by ``w2``; every pairing of a training feature
``i`` with a test feature ``j`` votes for the translation
``t = p_j - T_w2(p_i)``, weighted by ``wt_i`` and by their orientation
agreement. The votes are accumulated on a coarse grid (bilinear splatting,
then a small smoothing) to find the densest region, and the peak is then
polished by evaluating the exact score ``p(w)`` (Eq. 3) from precomputed,
smoothed test-feature maps: summing shifted maps gives the density the
sampled votes approximate, without sampling noise.

:func:`accumulate_votes` (with its pure-numpy reference) casts the votes; the
exact score is the scoring layer's :func:`posevote.scoring.score.gather_score`.
:func:`search_translations` drives them over a grid of ``w2``.
"""

from __future__ import annotations

import functools

import numba
import numpy as np
from numpy.typing import NDArray

from posevote.scoring.maps import TestMaps, vote_cell
from posevote.scoring.score import (
    gather_score,
    place_features,
    shifted_score,
    subsample_features,
)

# --- kernel 1: votes ----------------------------------------------------------

@numba.njit(cache=True, nogil=True)
def _lut_index(test_theta, th, lut_scale, index):  # pragma: no cover - compiled
    """The orientation table's entry for each pair of ``th`` with a run of test voters: a
    loop with no stores to the grid, which the compiler vectorises."""
    for m in range(test_theta.shape[0]):
        d = abs(test_theta[m] - th)
        d = min(d, np.pi - d)
        index[m] = np.int64(d * lut_scale + 0.5)


@numba.njit(cache=True, nogil=True)
def _pair_cells(tx, ty, test_w, wo, qx, qy, wi, xmax, ymax, row, cell, w00, w01, w10,
                w11):  # pragma: no cover - compiled
    """Each pair's vote cell (flat) and bilinear weights, for a run of test voters (at
    ``tx``, ``ty`` in cells, of weights ``test_w``) against one training voter at (qx, qy)
    of weight ``wi``; ``wo`` holds the pairs' orientation weights. A pair off the grid
    gets cell 0 and zero weights (its writes then add nothing). Vectorised by the
    compiler, as :func:`_lut_index`."""
    for m in range(tx.shape[0]):
        gx = tx[m] - qx
        gy = ty[m] - qy
        inside = (gx >= 0.0) & (gy >= 0.0) & (gx < xmax) & (gy < ymax)
        gx = gx if inside else 0.0
        gy = gy if inside else 0.0
        c0 = np.uint64(gx)
        r0 = np.uint64(gy)
        fx = gx - np.float64(c0)
        fy = gy - np.float64(r0)
        v = wi * (wo[m] if inside else 0.0) * test_w[m]
        vy = v * fy
        v0 = v - vy
        cell[m] = r0 * row + c0
        w00[m] = v0 - v0 * fx
        w01[m] = v0 * fx
        w10[m] = vy - vy * fx
        w11[m] = vy * fx


@numba.njit(cache=True, nogil=True)
def accumulate_votes(train_xy, train_theta, train_w, alpha, scale, test_xy, test_theta, test_w,
                     lut, cell, acc):  # pragma: no cover - compiled
    """Add the translation votes of one pose into ``acc`` (grid of cell ``cell`` px).

    ``acc[r, c]`` collects votes for ``t = (c * cell, r * cell)``, splatted
    bilinearly. Returns nothing; ``acc`` is updated in place. The test
    voters are sorted by orientation (in ``[0, pi)``), and a training
    voter's pairs are the run of them within the table's reach of its
    orientation (two runs where it wraps round): the pairs of zero weight
    are not visited. Each run's weights and cells are computed first, in
    vectorised loops, then written in the pairs' order.
    """
    lut_scale = (lut.shape[0] - 1) / (np.pi / 2.0)
    # The orientation difference past which the table is 0: the test voters
    # beyond it hold no pair with a vote.
    last = lut.shape[0] - 1
    while last >= 0 and lut[last] <= 0.0:
        last -= 1
    reach = (last + 0.5) / lut_scale + 1e-9
    # A table that never falls to 0 pairs every voter with every other, once.
    whole = reach >= np.pi / 2.0
    gh, gw = acc.shape
    # One flat index per pair, unsigned: no negative-index wrap checks on the
    # four writes (an eighth of the votes' time, the same sums).
    flat = acc.ravel()
    row = np.uint64(gw)
    xmax, ymax = gw - 1.0, gh - 1.0
    # Positions in cells once, not a division per pair.
    inv_cell = 1.0 / cell
    n_test = test_xy.shape[0]
    tx = np.empty(n_test)
    ty = np.empty(n_test)
    for j in range(n_test):
        tx[j] = test_xy[j, 0] * inv_cell
        ty[j] = test_xy[j, 1] * inv_cell
    index = np.empty(n_test, dtype=np.int64)
    wo = np.empty(n_test)
    cells = np.empty(n_test, dtype=np.uint64)
    w00 = np.empty(n_test)
    w01 = np.empty(n_test)
    w10 = np.empty(n_test)
    w11 = np.empty(n_test)
    ca, sa = np.cos(alpha), np.sin(alpha)
    for i in range(train_xy.shape[0]):
        wi = train_w[i]
        if wi <= 0.0:
            continue
        qx = scale * (ca * train_xy[i, 0] - sa * train_xy[i, 1]) * inv_cell
        qy = scale * (sa * train_xy[i, 0] + ca * train_xy[i, 1]) * inv_cell
        th = train_theta[i] + alpha
        th = th - np.pi * np.floor(th / np.pi)
        a_lo = th - reach
        a_hi = th + reach
        for run in range(2):
            if run == 0 and whole:
                lo, hi = 0, n_test
            elif run == 0:
                lo = np.searchsorted(test_theta, max(a_lo, 0.0))
                hi = np.searchsorted(test_theta, min(a_hi, np.pi))
            elif whole:
                break
            elif a_lo < 0.0:
                lo, hi = np.searchsorted(test_theta, a_lo + np.pi), n_test
            elif a_hi > np.pi:
                lo, hi = 0, np.searchsorted(test_theta, a_hi - np.pi)
            else:
                break
            n = hi - lo
            if n <= 0:
                continue
            # The run as slices of its own: indexed from an offset, the loops
            # vectorised worse (an eighth of the votes' time).
            _lut_index(test_theta[lo:hi], th, lut_scale, index)
            # The table's gather apart: in the loops above it stops their vectorising.
            for m in range(n):
                wo[m] = lut[index[m]]
            _pair_cells(tx[lo:hi], ty[lo:hi], test_w[lo:hi], wo, qx, qy, wi, xmax, ymax, row,
                        cells, w00, w01, w10, w11)
            for m in range(n):
                k = cells[m]
                flat[k] += w00[m]
                flat[k + np.uint64(1)] += w01[m]
                flat[k + row] += w10[m]
                flat[k + row + np.uint64(1)] += w11[m]


def accumulate_votes_reference(train_xy, train_theta, train_w, alpha, scale, test_xy, test_theta,
                               test_w, lut, cell, shape):
    """Pure-numpy :func:`accumulate_votes` over all pairs (for tests).

    Unlike the kernel it visits every pair; those the kernel skips, past the
    table's support, have a zero table value.
    """
    ca, sa = np.cos(alpha), np.sin(alpha)
    q = scale * np.stack([ca * train_xy[:, 0] - sa * train_xy[:, 1],
                          sa * train_xy[:, 0] + ca * train_xy[:, 1]], axis=1)
    th = np.mod(train_theta + alpha, np.pi)
    d = np.abs(test_theta[None, :] - th[:, None])
    d = np.where(d > np.pi / 2, np.pi - d, d)
    wo = lut[(d * (len(lut) - 1) / (np.pi / 2) + 0.5).astype(int)]
    v = train_w[:, None] * wo * test_w[None, :]
    gx = (test_xy[None, :, 0] - q[:, None, 0]) / cell
    gy = (test_xy[None, :, 1] - q[:, None, 1]) / cell
    acc = np.zeros(shape)
    c0 = np.floor(gx).astype(int)
    r0 = np.floor(gy).astype(int)
    ok = (v > 0) & (train_w[:, None] > 0) & (gx >= 0) & (gy >= 0) & (c0 < shape[1] - 1) & (
        r0 < shape[0] - 1)
    fx, fy, v, c0, r0 = (gx - c0)[ok], (gy - r0)[ok], v[ok], c0[ok], r0[ok]
    np.add.at(acc, (r0, c0), v * (1 - fx) * (1 - fy))
    np.add.at(acc, (r0, c0 + 1), v * fx * (1 - fy))
    np.add.at(acc, (r0 + 1, c0), v * (1 - fx) * fy)
    np.add.at(acc, (r0 + 1, c0 + 1), v * fx * fy)
    return acc


# --- driver ---------------------------------------------------------------------

@numba.njit(cache=True, nogil=True)
def _add_scaled(dst, src, weight):  # pragma: no cover - compiled
    """``dst += weight * src`` over two contiguous rows: a loop of its own, which the
    compiler vectorises (inlined in the blur's, it did not)."""
    for c in range(dst.shape[0]):
        dst[c] += weight * src[c]


@numba.njit(cache=True, nogil=True)
def _blur(src, acc, tmp, taps):  # pragma: no cover - compiled
    """Separable smoothing of ``src`` into ``acc`` with the symmetric kernel ``taps`` (0 outside).

    ``src`` is read in ``acc``'s precision, all of it before ``acc`` is
    written (it may be ``acc`` itself): the search blurs its double-precision
    votes into a single-precision grid without a copy between.

    The taps are added along whole rows (contiguous, no branch per tap),
    four to a pass over the row and in their order, so that every cell sums
    the same terms in the same order as a tap loop per cell would (a row
    read past the grid's edge adds zeros, which change no sum).
    """
    gh, gw = acc.shape
    n = taps.shape[0]
    r = n // 2
    pad = np.zeros(gw + 2 * r, dtype=acc.dtype)
    for row in range(gh):
        pad[r:r + gw] = src[row]
        t = tmp[row]
        t[:] = 0.0
        k = 0
        while k + 4 <= n:
            w0, w1, w2, w3 = taps[k], taps[k + 1], taps[k + 2], taps[k + 3]
            p0, p1 = pad[k:k + gw], pad[k + 1:k + 1 + gw]
            p2, p3 = pad[k + 2:k + 2 + gw], pad[k + 3:k + 3 + gw]
            for c in range(gw):
                t[c] = (((t[c] + w0 * p0[c]) + w1 * p1[c]) + w2 * p2[c]) + w3 * p3[c]
            k += 4
        for j in range(k, n):
            _add_scaled(t, pad[j:j + gw], taps[j])
    for row in range(gh):
        a = acc[row]
        a[:] = 0.0
        k, last = max(-r, -row), min(r, gh - 1 - row)
        while k + 3 <= last:
            w0, w1, w2, w3 = taps[k + r], taps[k + 1 + r], taps[k + 2 + r], taps[k + 3 + r]
            s0, s1, s2, s3 = tmp[row + k], tmp[row + k + 1], tmp[row + k + 2], tmp[row + k + 3]
            for c in range(gw):
                a[c] = (((a[c] + w0 * s0[c]) + w1 * s1[c]) + w2 * s2[c]) + w3 * s3[c]
            k += 4
        for j in range(k, last + 1):
            _add_scaled(a, tmp[row + j], taps[j + r])


@numba.njit(cache=True, nogil=True)
def _argmax_nonnegative(grid):  # pragma: no cover - compiled
    """``np.argmax`` of a contiguous single-precision grid of non-negative values (flat).

    Non-negative floats order as their bit patterns do as integers, and an
    integer maximum is a loop the compiler vectorises (a float's, with its
    NaN rules, it does not): a sixth of ``np.argmax``'s time on a vote grid.
    The first cell holding the maximum is returned, as ``np.argmax`` does.
    """
    bits = grid.reshape(-1).view(np.int32)
    top = np.int32(0)
    for i in range(bits.shape[0]):
        b = bits[i]
        top = b if b > top else top
    for i in range(bits.shape[0]):
        if bits[i] == top:
            return i
    return 0


def blur_reference(acc: NDArray[np.float64], taps: NDArray[np.float64]) -> NDArray[np.float64]:
    """:func:`_blur` in numpy, a copy (for tests)."""
    r = len(taps) // 2
    padded = np.pad(acc, r)
    rows = sum(taps[k] * padded[:, k:k + acc.shape[1]] for k in range(len(taps)))[r:-r]
    padded = np.pad(rows, ((r, r), (0, 0)))
    return sum(taps[k] * padded[k:k + acc.shape[0]] for k in range(len(taps)))


@functools.lru_cache(maxsize=64)
def blur_taps(sigma_cells: float) -> NDArray[np.float64]:
    """Normalised Gaussian taps (3 sigma) for smoothing the vote grid (shared: do not modify).

    Cached: every search of an image asks for the same few widths.
    """
    r = max(1, int(np.ceil(3.0 * sigma_cells)))
    x = np.arange(-r, r + 1, dtype=np.float64)
    taps = np.exp(-x * x / (2.0 * max(sigma_cells, 1e-3) ** 2))
    return taps / taps.sum()


_POLISH_RADIUS = 8
#: A polished search call polishes at most this many of its (in-plane angle,
#: scale) steps: those whose exact score at their vote cell is highest, the
#: others keeping that score (the cluttered preset's 13 in-plane angles).
POLISHED_STEPS = 5
#: The polish's climb compares shifts on about this many features.
_CLIMB_FEATURES = 250


@numba.njit(cache=True, nogil=True)
def _climb(density, frame, train_w, px, py, obins, ofrac, cache, vals, pu, pv, step, diagonal,
           lattice):  # pragma: no cover - compiled
    """Hill-climb the shifted score from (pu, pv) to a peak of it, on a lattice of
    ``lattice`` pixels.

    Moves to the best of the 8 neighbours (``diagonal``) or of the 4, while
    one beats the centre; ``vals`` is left holding the peak's neighbourhood
    (-inf outside the polish radius) and ``cache`` the scores (``step`` as in
    :func:`shifted_score`) by shift. Returns the peak (pu, pv).
    """
    r = _POLISH_RADIUS
    for _ in range(4 * r):
        for k in range(9):
            dr, dc = k // 3, k % 3
            if not diagonal and dr != 1 and dc != 1:
                continue
            iu = pu + lattice * (dc - 1)
            iv = pv + lattice * (dr - 1)
            if abs(iu) > r or abs(iv) > r:
                vals[dr, dc] = -np.inf
                continue
            val = cache[iv + r, iu + r]
            if np.isnan(val):
                val = shifted_score(density, frame, train_w, px, py, obins, ofrac, iu, iv, step)
                cache[iv + r, iu + r] = val
            vals[dr, dc] = val
        best = 4
        bv = vals[1, 1]
        for k in range(9):
            if not diagonal and k // 3 != 1 and k % 3 != 1:
                continue
            if vals[k // 3, k % 3] > bv:
                bv = vals[k // 3, k % 3]
                best = k
        if best == 4:
            break
        pu += lattice * (best % 3 - 1)
        pv += lattice * (best // 3 - 1)
    return pu, pv


@numba.njit(cache=True, nogil=True)
def _polish(density, frame, train_xy, train_theta, train_w, alpha, scale, u0, v0, px, py, obins,
            ofrac, cache):  # pragma: no cover - compiled
    """Hill-climb the exact score on a 1-pixel lattice, then a parabolic step."""
    cu = np.floor(u0 + 0.5)
    cv = np.floor(v0 + 0.5)
    place_features(frame, density.shape[0], train_xy, train_theta, alpha, scale, cu, cv, px, py,
                   obins, ofrac)
    vals = np.empty((3, 3))
    # The climb strides 2 pixels and compares shifts on a subset of the
    # features; then, on all of them, it climbs the 1-pixel 4-neighbours, so
    # that the peak is one of the exact score, for fewer scores than a
    # 1-pixel climb from the vote cell.
    step = max(1, train_w.shape[0] // _CLIMB_FEATURES)
    cache[:, :] = np.nan
    pu, pv = _climb(density, frame, train_w, px, py, obins, ofrac, cache, vals, 0, 0, step, True,
                    2)
    if step > 1:
        cache[:, :] = np.nan
    pu, pv = _climb(density, frame, train_w, px, py, obins, ofrac, cache, vals, pu, pv, 1, False,
                    1)
    for k in (1, 3, 5, 7):
        if vals[k // 3, k % 3] == -np.inf:
            vals[k // 3, k % 3] = -1.0
    # Parabolic interpolation through the centre row and column.
    du = 0.0
    dv = 0.0
    peak = vals[1, 1]
    den_u = vals[1, 0] - 2.0 * vals[1, 1] + vals[1, 2]
    den_v = vals[0, 1] - 2.0 * vals[1, 1] + vals[2, 1]
    if den_u < 0.0 and vals[1, 0] >= 0.0 and vals[1, 2] >= 0.0:
        du = 0.5 * (vals[1, 0] - vals[1, 2]) / den_u
        du = min(0.5, max(-0.5, du))
        peak -= 0.25 * (vals[1, 0] - vals[1, 2]) * du
    if den_v < 0.0 and vals[0, 1] >= 0.0 and vals[2, 1] >= 0.0:
        dv = 0.5 * (vals[0, 1] - vals[2, 1]) / den_v
        dv = min(0.5, max(-0.5, dv))
        peak -= 0.25 * (vals[0, 1] - vals[2, 1]) * dv
    return peak, cu + pu + du, cv + pv + dv


@numba.njit(cache=True, nogil=True)
def _search_kernel(train_xy, train_theta, train_w, alphas, scales, test_xy, test_theta, test_w,
                   lut, density, frame, h, w, cell, taps, n_candidates, voters,
                   polish, out_score, out_t):  # pragma: no cover - compiled
    gh = int(np.ceil(h / cell)) + 1
    gw = int(np.ceil(w / cell)) + 1
    votes = np.zeros((gh, gw))
    # The votes are summed in double precision (the scattered adds are no
    # faster in single) and blurred in single, in two-thirds of the time: they
    # only rank cells, for the exact score to judge.
    acc = np.zeros((gh, gw), dtype=np.float32)
    tmp = np.zeros((gh, gw), dtype=np.float32)
    taps = taps.astype(np.float32)
    # The polish's per-pose tables; an unpolished search needs none.
    m = train_xy.shape[0] if polish else 0
    px = np.empty(m)
    py = np.empty(m)
    obins = np.empty((m, 2), dtype=np.int64)
    ofrac = np.empty(m)
    cache = np.empty((2 * _POLISH_RADIUS + 1, 2 * _POLISH_RADIUS + 1))
    voter_xy = train_xy[voters]
    voter_theta = train_theta[voters]
    voter_w = train_w[voters]
    n_a, n_s = alphas.shape[0], scales.shape[0]
    starts = np.full(n_a * n_s, -1.0)
    peaks = np.full((n_a * n_s, 2), -1, dtype=np.int64)
    for a in range(n_a):
        for s in range(n_s):
            votes[:, :] = 0.0
            accumulate_votes(voter_xy, voter_theta, voter_w, alphas[a], scales[s], test_xy,
                             test_theta, test_w, lut, cell, votes)
            _blur(votes, acc, tmp, taps)
            # The vote peaks are ranked by the exact score at their cell, and
            # only the best of them is polished (hill-climbing every peak
            # cost a quarter of the search for the same winner, nearly always).
            best_start = -1.0
            best_r = -1
            best_c = -1
            for _ in range(n_candidates):
                flat = _argmax_nonnegative(acc)
                r = flat // gw
                c = flat % gw
                if acc[r, c] <= 0.0:
                    break
                if n_candidates == 1 and polish:
                    best_r = r
                    best_c = c
                    break
                start = gather_score(density, frame, train_xy, train_theta, train_w, alphas[a],
                                     scales[s], c * cell, r * cell)
                if start > best_start:
                    best_start = start
                    best_r = r
                    best_c = c
                # Suppress this peak's neighbourhood before the next candidate.
                sup = taps.shape[0] // 2 + 1
                for rr in range(max(0, r - sup), min(gh, r + sup + 1)):
                    for cc in range(max(0, c - sup), min(gw, c + sup + 1)):
                        acc[rr, cc] = 0.0
            starts[a * n_s + s] = best_start
            peaks[a * n_s + s, 0] = best_r
            peaks[a * n_s + s, 1] = best_c
    # Of many steps, only those whose exact score at their vote cell is among
    # the POLISHED_STEPS best are polished (without scores, every one is).
    polished = np.zeros(n_a * n_s, dtype=np.bool_)
    if polish and n_candidates > 1 and n_a * n_s > POLISHED_STEPS:
        for q in np.argsort(-starts, kind="mergesort")[:POLISHED_STEPS]:
            polished[q] = True
    elif polish:
        polished[:] = True
    for a in range(n_a):
        for s in range(n_s):
            k = a * n_s + s
            best_r, best_c = peaks[k, 0], peaks[k, 1]
            best_score = starts[k]
            best_u = max(best_c, 0) * cell
            best_v = max(best_r, 0) * cell
            if best_r >= 0 and polished[k]:
                best_score, best_u, best_v = _polish(density, frame, train_xy, train_theta,
                                                     train_w, alphas[a], scales[s], best_c * cell,
                                                     best_r * cell, px, py, obins, ofrac, cache)
            out_score[a, s] = max(best_score, 0.0)
            out_t[a, s, 0] = best_u
            out_t[a, s, 1] = best_v


@numba.njit(cache=True, nogil=True)
def _polish_steps(train_xy, train_theta, train_w, alphas, scales, density, frame, score, t,
                  out_score, out_t):  # pragma: no cover - compiled
    """:func:`_polish` of every step of an unpolished search from its vote cell (``t``)."""
    m = train_xy.shape[0]
    px = np.empty(m)
    py = np.empty(m)
    obins = np.empty((m, 2), dtype=np.int64)
    ofrac = np.empty(m)
    cache = np.empty((2 * _POLISH_RADIUS + 1, 2 * _POLISH_RADIUS + 1))
    for a in range(alphas.shape[0]):
        for s in range(scales.shape[0]):
            out_score[a, s] = score[a, s]
            out_t[a, s, 0] = t[a, s, 0]
            out_t[a, s, 1] = t[a, s, 1]
            # A step without a vote peak scored 0 at the origin.
            if score[a, s] <= 0.0 and t[a, s, 0] == 0.0 and t[a, s, 1] == 0.0:
                continue
            best, u, v = _polish(density, frame, train_xy, train_theta, train_w, alphas[a],
                                 scales[s], t[a, s, 0], t[a, s, 1], px, py, obins, ofrac, cache)
            out_score[a, s] = max(best, 0.0)
            out_t[a, s, 0] = u
            out_t[a, s, 1] = v


def polish_translations(maps: TestMaps, train_xy: NDArray[np.float64],
                        train_theta: NDArray[np.float64], train_w: NDArray[np.float64], *,
                        inplanes: NDArray[np.float64], scales: NDArray[np.float64],
                        score: NDArray[np.float64], translation: NDArray[np.float64]
                        ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Polish the steps of an unpolished :func:`search_translations`, later.

    ``score`` and ``translation`` are what that search returned with
    ``polish=False`` for the same features (subsampled as it used them),
    angles and scales; each step is hill-climbed from its vote cell as a
    polished search would have done (the same scores and translations, but
    that every step is polished here: :data:`POLISHED_STEPS` does not apply).

    Returns
    -------
    score : ndarray, shape (A, S)
    translation : ndarray, shape (A, S, 2)
    """
    out_score = np.zeros((len(inplanes), len(scales)))
    out_t = np.zeros((len(inplanes), len(scales), 2))
    if len(train_theta):
        _polish_steps(np.ascontiguousarray(train_xy, dtype=np.float64),
                      np.ascontiguousarray(train_theta, dtype=np.float64),
                      np.ascontiguousarray(train_w, dtype=np.float64),
                      np.asarray(inplanes, dtype=np.float64), np.asarray(scales, dtype=np.float64),
                      maps.density, maps.frame, np.ascontiguousarray(score, dtype=np.float64),
                      np.ascontiguousarray(translation, dtype=np.float64), out_score, out_t)
    return out_score, out_t


def strongest_voters(weight: NDArray[np.float64], max_voters: int | None) -> NDArray[np.int64]:
    """Indices, ascending, of the ``max_voters`` largest weights (all when None or fewer).

    The heaviest features carry most of the exact score, so their votes
    peak where it does (an even stride through the features finds fewer
    cars: docs/history/METHOD-NOTES.md, "Speed").
    """
    n = len(weight)
    if max_voters is None or n <= max_voters:
        return np.arange(n, dtype=np.int64)
    top = np.argpartition(-weight, max_voters - 1)[:max_voters]
    return np.sort(top).astype(np.int64)


def search_translations(maps: TestMaps, train_xy: NDArray[np.float64],
                        train_theta: NDArray[np.float64], train_w: NDArray[np.float64], *,
                        inplanes: NDArray[np.float64], scales: NDArray[np.float64],
                        cell: float | None = None, n_candidates: int = 3,
                        max_voters: int | None = 200, max_features: int | None = None,
                        polish: bool = True, voters: NDArray[np.int64] | None = None
                        ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Best translation and its score for every (in-plane angle, scale) step.

    Parameters
    ----------
    maps : TestMaps
        The prepared test image.
    train_xy, train_theta, train_w : ndarray
        Training features of one viewpoint (object-centred) and their vote
        weights (``wt_i * K1``), already normalised to sum to 1.
    inplanes : ndarray, shape (A,)
        In-plane angles, radians.
    scales : ndarray, shape (S,)
        Scales (image pixels per model unit).
    cell : float, optional
        Vote grid cell, pixels; by default two-thirds of the maps' position
        kernel width (at least 1.5). Votes are smoothed with that kernel.
    n_candidates : int, optional
        Vote peaks per step whose exact score is read at their vote cell;
        the best of them is polished (hill-climbed to the pixel).
    max_voters : int or None, optional
        At most this many training features vote: those of largest weight
        (:func:`strongest_voters`); all of them count in the exact score.
    max_features : int or None, optional
        If given, at most about this many training features (an even stride
        through them, their weights scaled to the same total) take part at
        all, in the votes and in the exact score. A pooled category model has
        thousands of features per viewpoint, and the exact score of every
        polished candidate reads all of them.
    polish : bool, optional
        Hill-climb the best candidate to the pixel (the score's peak): of
        more than :data:`POLISHED_STEPS` steps, those whose exact score at
        their vote cell is highest only. False keeps the exact score at its
        vote cell, a cell's width from the peak at most: enough to rank
        probes, at a fraction of the cost.
    voters : ndarray of int, optional
        The voting features' indices, when the caller has them already:
        ``strongest_voters(w, max_voters)`` of the (subsampled) weights.

    Returns
    -------
    score : ndarray, shape (A, S)
        ``p(w)`` at the best translation (Eq. 3 with the model's weights).
    translation : ndarray, shape (A, S, 2)
        Best reference-point position ``(u, v)``, pixels.
    """
    out_score = np.zeros((len(inplanes), len(scales)))
    out_t = np.zeros((len(inplanes), len(scales), 2))
    if cell is None:
        cell = vote_cell(maps.position_sigma)
    taps = blur_taps(maps.position_sigma / cell)
    train_xy, train_theta, train_w = subsample_features(train_xy, train_theta, train_w,
                                                        max_features)
    if voters is None:
        voters = strongest_voters(train_w, max_voters)
    if len(train_theta) and len(maps.vote_theta):
        _search_kernel(train_xy, train_theta, train_w, np.asarray(inplanes, dtype=np.float64),
                       np.asarray(scales, dtype=np.float64), maps.vote_xy, maps.vote_theta,
                       maps.vote_weight, maps.lut,
                       maps.density, maps.frame, maps.shape[0], maps.shape[1], float(cell), taps,
                       int(n_candidates), voters, bool(polish), out_score, out_t)
    return out_score, out_t
