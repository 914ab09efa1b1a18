"""The scoring layer: a model placed on the test maps and scored (Eq. 3), below search and refinement.

Everything that reads how well the model explains the image at one pose lives
here, so that the search (:mod:`posevote.inference`) and every refinement
(:mod:`posevote.refinement` and the extensions) score a pose the same way:

- :func:`viewpoint_features` collects the training features of the views near
  a viewpoint (Eq. 1 at ``w1``) with their vote weights;
- :func:`gather_score` is the exact ``p(w)`` of those features placed by
  ``w2``, ``w3`` on the tabulated test density (:mod:`posevote.scoring.maps`),
  with :func:`place_features` / :func:`shifted_score` for the shifts of one
  placement and :func:`density_at` / :func:`gather_score_reference` in numpy;
- :func:`explained_sums` is the other direction, the model's kernel sum at
  each test edge (Eq. 5's terms);
- :class:`ScoreSetup` holds the kernel widths and weights every score reads,
  and :func:`narrow_maps` tabulates the test image with the narrow kernel.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from posevote.features.edges import EdgeFeatures
from posevote.model.density import PoseModel, near_views
from posevote.model.kernels import K1_CUTOFF, ORIENTATION_KAPPA, orientation_kernel, position_kernel
from posevote.model.morph import morphed_positions
from posevote.results import Hypothesis
from posevote.scoring.maps import TestMaps, prepare_test


@dataclass(frozen=True, kw_only=True)
class ScoreSetup:
    """The kernels and weights with which a fitted model scores a pose.

    Attributes
    ----------
    position_sigma : float
        The narrow (refinement) position kernel, pixels at scale 1.
    edge_spacing : float
        Spacing of the test edge points, pixels (normalises phi).
    viewpoint_kappa : float
        Concentration of the pose kernel K1.
    use_weights : bool
        Use the features' weights (Eq. 4).
    n_threads : int
        Viewpoints probed at once (the search's; the time, not the result).
    """

    position_sigma: float
    edge_spacing: float
    viewpoint_kappa: float
    use_weights: bool = True
    n_threads: int = 1


def narrow_maps(features: EdgeFeatures, shape: tuple[int, int], setup: ScoreSetup, *,
                scale: float = 1.0, region: tuple[int, int, int, int] | None = None) -> TestMaps:
    """The test image tabulated with the narrow kernel, unsaturated (the refinements' maps).

    ``scale`` is the factor the features were divided by (object units at that
    scale, :func:`posevote.scoring.maps.scaled_features`); ``region`` tabulates
    the maps only there (:func:`posevote.scoring.maps.prepare_test`).
    """
    return prepare_test(features, shape, position_sigma=setup.position_sigma,
                        orientation_kappa=ORIENTATION_KAPPA,
                        edge_spacing=setup.edge_spacing / scale, density_cap=None,
                        chance_width=None, region=region)


@numba.njit(cache=True, nogil=True)
def gather_score(density, frame, train_xy, train_theta, train_w, alpha, scale, tu, tv
                 ):  # pragma: no cover - compiled
    """Sum of ``wt_i * phi(T_w x_i)`` with ``T_w`` = (alpha, scale, (tu, tv)).

    ``phi`` is read from the tabulated maps (``frame``: :attr:`TestMaps.frame`)
    bilinearly in position and linearly in orientation; outside their
    window it is 0.
    """
    n_bins = density.shape[0]
    bin_width = np.pi / n_bins
    inv = frame[5]
    # The pose straight to grid units: a pixel (u, v) is at ((u - off_u) inv, (v - off_v) inv).
    ca, sa = scale * inv * np.cos(alpha), scale * inv * np.sin(alpha)
    gu, gv = (tu - frame[4]) * inv, (tv - frame[6]) * inv
    total = 0.0
    for i in range(train_xy.shape[0]):
        wi = train_w[i]
        if wi <= 0.0:
            continue
        x = ca * train_xy[i, 0] - sa * train_xy[i, 1] + gu
        y = sa * train_xy[i, 0] + ca * train_xy[i, 1] + gv
        if x < frame[0] or y < frame[1] or x >= frame[2] or y >= frame[3]:
            continue
        th = train_theta[i] + alpha
        th = th - np.pi * np.floor(th / np.pi)
        f = th / bin_width - 0.5
        fb = np.floor(f)
        ft = f - fb
        # fb lies in [-1, n_bins - 1]: wrapped by a comparison, not an integer division
        # (which cost the search's exact scores dearly).
        b0 = int(fb)
        if b0 < 0:
            b0 += n_bins
        b1 = b0 + 1 if b0 + 1 < n_bins else 0
        total += wi * phi_at(density, x, y, b0, b1, ft)
    return total


@numba.njit(cache=True, nogil=True)
def phi_at(density, x, y, b0, b1, ft):  # pragma: no cover - compiled
    """phi at grid position (x, y) inside the window, between bins ``b0`` and ``b1``:
    bilinear (a position before the first cell reads it)."""
    if x < 0.0:
        x = 0.0
    if y < 0.0:
        y = 0.0
    c0 = int(x)
    r0 = int(y)
    fx = x - c0
    fy = y - r0
    v0 = ((1 - fx) * (1 - fy) * density[b0, r0, c0] + fx * (1 - fy) * density[b0, r0, c0 + 1]
          + (1 - fx) * fy * density[b0, r0 + 1, c0] + fx * fy * density[b0, r0 + 1, c0 + 1])
    v1 = ((1 - fx) * (1 - fy) * density[b1, r0, c0] + fx * (1 - fy) * density[b1, r0, c0 + 1]
          + (1 - fx) * fy * density[b1, r0 + 1, c0] + fx * fy * density[b1, r0 + 1, c0 + 1])
    return (1.0 - ft) * v0 + ft * v1


@numba.njit(cache=True, nogil=True)
def place_features(frame, n_bins, xy, theta, alpha, scale, u0, v0, px, py, obins, ofrac
                   ):  # pragma: no cover - compiled
    """The features turned, scaled and moved to (u0, v0) as :func:`gather_score` places
    them, in the grid's units (``px``, ``py``), and their orientation bins
    (``obins``, ``ofrac``), in place.

    The pose's shifts (:func:`shifted_score`) then skip the turn and the bins.
    """
    bin_width = np.pi / n_bins
    inv = frame[5]
    ca, sa = scale * inv * np.cos(alpha), scale * inv * np.sin(alpha)
    gu, gv = (u0 - frame[4]) * inv, (v0 - frame[6]) * inv
    for i in range(xy.shape[0]):
        px[i] = ca * xy[i, 0] - sa * xy[i, 1] + gu
        py[i] = sa * xy[i, 0] + ca * xy[i, 1] + gv
        th = theta[i] + alpha
        th = th - np.pi * np.floor(th / np.pi)
        f = th / bin_width - 0.5
        fb = np.floor(f)
        ofrac[i] = f - fb
        b0 = int(fb)
        if b0 < 0:
            b0 += n_bins
        obins[i, 0] = b0
        obins[i, 1] = b0 + 1 if b0 + 1 < n_bins else 0


@numba.njit(cache=True, nogil=True)
def shifted_score(density, frame, weight, px, py, obins, ofrac, du, dv, step
                  ):  # pragma: no cover - compiled
    """:func:`gather_score` of the features placed by :func:`place_features`, shifted by
    (du, dv) pixels; with ``step`` > 1, of every ``step``-th feature only (a
    cheaper estimate, for comparing shifts)."""
    gu = du * frame[5]
    gv = dv * frame[5]
    total = 0.0
    for i in range(0, weight.shape[0], step):
        wi = weight[i]
        x = px[i] + gu
        y = py[i] + gv
        if wi <= 0.0 or x < frame[0] or y < frame[1] or x >= frame[2] or y >= frame[3]:
            continue
        total += wi * phi_at(density, x, y, obins[i, 0], obins[i, 1], ofrac[i])
    return total


def density_at(maps: TestMaps, xy: NDArray[np.float64], theta: NDArray[np.float64]
               ) -> NDArray[np.float64]:
    """phi at each point and orientation, interpolated as :func:`phi_at` reads it.

    Bilinear in position on the maps' grid, linear in orientation; 0
    outside their window.
    """
    from scipy.ndimage import map_coordinates

    n_bins = maps.density.shape[0]
    u_lo, v_lo, u_hi, v_hi = maps.window
    k = maps.grid
    f = np.mod(theta, np.pi) / (np.pi / n_bins) - 0.5
    b0 = np.floor(f).astype(int) % n_bins
    b1 = (b0 + 1) % n_bins
    ft = f - np.floor(f)
    x, y = xy[:, 0], xy[:, 1]
    inside = (x >= u_lo) & (y >= v_lo) & (x < u_hi) & (y < v_hi)
    gx = np.maximum((x - 0.5 * (k - 1) - maps.origin[0]) / k, 0.0)
    gy = np.maximum((y - 0.5 * (k - 1) - maps.origin[1]) / k, 0.0)
    d = maps.density.astype(np.float64)
    v0 = map_coordinates(d, [b0, gy, gx], order=1, mode="nearest")
    v1 = map_coordinates(d, [b1, gy, gx], order=1, mode="nearest")
    return np.where(inside, (1 - ft) * v0 + ft * v1, 0.0)


def gather_score_reference(maps, train_xy, train_theta, train_w, alpha, scale, tu, tv):
    """Pure-numpy :func:`gather_score` (for tests)."""
    ca, sa = np.cos(alpha), np.sin(alpha)
    x = scale * (ca * train_xy[:, 0] - sa * train_xy[:, 1]) + tu
    y = scale * (sa * train_xy[:, 0] + ca * train_xy[:, 1]) + tv
    values = density_at(maps, np.stack([x, y], axis=1), train_theta + alpha)
    return float(np.sum(np.where(train_w > 0, train_w * values, 0.0)))


def subsample_features(xy: NDArray[np.float64], theta: NDArray[np.float64],
                       weight: NDArray[np.float64], max_features: int | None
                       ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """At most about ``max_features`` of the features (an even stride), their weights
    scaled to the same total; contiguous float64 arrays (the kernels' own)."""
    if max_features is not None and len(theta) > max_features:
        keep = slice(0, None, int(np.ceil(len(theta) / max_features)))
        total = float(np.sum(weight))
        xy, theta, weight = xy[keep], theta[keep], weight[keep]
        subtotal = float(np.sum(weight))
        weight = weight * (total / subtotal) if subtotal > 0 else weight
    return (np.ascontiguousarray(xy, dtype=np.float64), np.ascontiguousarray(theta, dtype=np.float64),
            np.ascontiguousarray(weight, dtype=np.float64))


def median_spacing(directions: NDArray[np.float64]) -> float:
    """Median angle between a viewing direction and its nearest neighbour, radians (pi for
    fewer than two)."""
    if len(directions) < 2:
        return float(np.pi)
    cosines = np.clip(directions @ directions.T, -1.0, 1.0)
    np.fill_diagonal(cosines, -1.0)
    return float(np.median(np.arccos(cosines.max(axis=1))))


@dataclass(frozen=True, kw_only=True, eq=False)
class ViewpointFeatures:
    """The training features that describe one viewpoint (psi at w1).

    Attributes
    ----------
    xy, theta : ndarray
        Object-centred features of the training views near the viewpoint.
    weight : ndarray
        Vote weights ``wt_i * K1(w1, w_i)``, normalised to sum to 1.
    box : ndarray, shape (2,)
        Object box width and height at the viewpoint, model units.
    """

    xy: NDArray[np.float64]
    theta: NDArray[np.float64]
    weight: NDArray[np.float64]
    box: NDArray[np.float64]


def viewpoint_features(model: PoseModel, azimuth: float, elevation: float, *,
                       viewpoint_kappa: float, use_weights: bool = True, k1_cutoff: float = 0.1
                       ) -> ViewpointFeatures:
    """Collect the training features of the views near a viewpoint (Eq. 1 at w1).

    Training views whose pose kernel K1 is below ``k1_cutoff`` are left out
    (the nearest view always takes part). With a morphed model (``model.shift``)
    the features move toward the viewpoint (:mod:`posevote.model.morph`).
    """
    views, k1 = near_views(model, azimuth, elevation, kappa=viewpoint_kappa, k1_cutoff=k1_cutoff)
    idx = model.features_of(views)
    w = k1[model.view[idx]] * (model.weight[idx] if use_weights else 1.0)
    total = w.sum()
    xy = model.xy[idx]
    if model.shift is not None and model.view_neighbour is not None:
        xy = morphed_positions(xy, model.shift[idx], model.view[idx], azimuth,
                               model.view_azimuth, model.view_neighbour, elevation=elevation,
                               view_elevation=model.view_elevation)
    return ViewpointFeatures(xy=xy, theta=model.theta[idx],
                             weight=w / total if total > 0 else w,
                             box=np.average(model.view_box[views], axis=0, weights=k1[views]))


@numba.njit(cache=True, nogil=True)
def _explained_sums(xy, theta, strength, test_xy, test_theta, order, sigma, kappa, reach
                    ):  # pragma: no cover - compiled
    """:func:`explained_sums` over the test points sorted by x (``order``)."""
    n = test_xy.shape[0]
    sorted_x = np.empty(n)
    for k in range(n):
        sorted_x[k] = test_xy[order[k], 0]
    # cos 2(a - b) from the doubled angles' cosines and sines, and both kernels
    # under one exponential: the pairs' transcendentals were the whole cost.
    tc = np.cos(2.0 * test_theta)
    ts = np.sin(2.0 * test_theta)
    total = np.zeros(n)
    for i in range(xy.shape[0]):
        mc = np.cos(2.0 * theta[i])
        ms = np.sin(2.0 * theta[i])
        k = np.searchsorted(sorted_x, xy[i, 0] - reach)
        while k < n and sorted_x[k] <= xy[i, 0] + reach:
            j = order[k]
            dx = test_xy[j, 0] - xy[i, 0]
            dy = test_xy[j, 1] - xy[i, 1]
            d2 = dx * dx + dy * dy
            if d2 <= reach * reach:
                total[j] += strength[i] * np.exp(-d2 / (2.0 * sigma * sigma)
                                                 + kappa * (mc * tc[j] + ms * ts[j] - 1.0))
            k += 1
    return total


def explained_sums(xy: NDArray[np.float64], theta: NDArray[np.float64],
                   strength: NDArray[np.float64], test_xy: NDArray[np.float64],
                   test_theta: NDArray[np.float64], sigma: float, kappa: float, *,
                   reach_sigmas: float = 3.0) -> NDArray[np.float64]:
    """For each test point, the model points' kernel sum within reach (Eq. 5's terms).

    ``strength[i] * exp(-d^2 / 2 sigma^2) * exp(kappa (cos 2 dtheta - 1))``
    summed over the model points ``i`` within ``reach_sigmas * sigma`` of the
    test point (3 for Eq. 5).
    """
    f64 = np.float64
    test_xy = np.ascontiguousarray(test_xy, dtype=f64)
    order = np.argsort(test_xy[:, 0], kind="stable") if len(test_xy) else np.zeros(0, np.int64)
    return _explained_sums(np.ascontiguousarray(xy, dtype=f64),
                           np.ascontiguousarray(theta, dtype=f64),
                           np.ascontiguousarray(strength, dtype=f64), test_xy,
                           np.ascontiguousarray(test_theta, dtype=f64), order, float(sigma),
                           float(kappa), float(reach_sigmas) * float(sigma))


def explained_sums_reference(xy: NDArray[np.float64], theta: NDArray[np.float64],
                             strength: NDArray[np.float64], test_xy: NDArray[np.float64],
                             test_theta: NDArray[np.float64], sigma: float, kappa: float
                             ) -> NDArray[np.float64]:
    """:func:`explained_sums` by k-d trees and the kernels of :mod:`posevote.model.kernels`."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(xy).sparse_distance_matrix(cKDTree(test_xy), 3.0 * sigma,
                                               output_type="ndarray")
    i, j, dist = pairs["i"], pairs["j"], pairs["v"]
    terms = (strength[i] * position_kernel(dist ** 2, sigma)
             * orientation_kernel(theta[i] - test_theta[j], kappa))
    return np.bincount(j, weights=terms, minlength=len(test_xy)).astype(np.float64)


def features_at(hypothesis: Hypothesis, model: PoseModel, *, viewpoint_kappa: float,
                   use_weights: bool, k1_cutoff: float, max_features: int | None
                   ) -> ViewpointFeatures:
    """The features of the views near the hypothesis's viewpoint (:func:`viewpoint_features`),
    at most about ``max_features`` of them (:func:`subsample_features`)."""
    feats = viewpoint_features(model, hypothesis.azimuth, hypothesis.elevation,
                               viewpoint_kappa=viewpoint_kappa, use_weights=use_weights,
                               k1_cutoff=k1_cutoff)
    if max_features is not None and feats.weight.sum() > 0:
        xy, theta, weight = subsample_features(feats.xy, feats.theta, feats.weight, max_features)
        feats = replace(feats, xy=xy, theta=theta, weight=weight)
    return feats


def pose_score(hypothesis: Hypothesis, model: PoseModel, maps: TestMaps, *,
               viewpoint_kappa: float, use_weights: bool = True, k1_cutoff: float = 0.1,
               max_features: int | None = None) -> float:
    """The exact p(w) of ``model`` at the hypothesis's pose as it stands (no polish).

    Parameters as in :func:`posevote.refinement.local.polish_pose`, whose
    starting score it is.
    """
    feats = features_at(hypothesis, model, viewpoint_kappa=viewpoint_kappa,
                           use_weights=use_weights, k1_cutoff=k1_cutoff,
                           max_features=max_features)
    if feats.weight.sum() <= 0:
        return 0.0
    return float(gather_score(maps.density, maps.frame, feats.xy, feats.theta, feats.weight,
                              hypothesis.inplane, hypothesis.scale, *hypothesis.position))


def score_options(setup: ScoreSetup) -> dict[str, Any]:
    """The pose kernel and weights the polishes score with."""
    return {"viewpoint_kappa": setup.viewpoint_kappa, "use_weights": setup.use_weights,
            "k1_cutoff": K1_CUTOFF}


#: Fewer test edges than this in a probe's box: it explains nothing.
MIN_BOX_EDGES = 5
