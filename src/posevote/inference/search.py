"""Pose inference (Fig. 2): probes of p(w) over viewpoint x in-plane angle x scale.

For each discrete viewpoint ``w1`` the training features of nearby training
views (pose kernel K1) are collected with vote weights ``wt_i * K1``; for
each in-plane/scale step ``w2`` the translation ``w3`` is found by voting
(:mod:`posevote.inference.voting`). The result is a :class:`ProbeSet`: the
set of (pose, score) pairs approximating p(w) at discrete probes.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from posevote.geometry import viewing_direction
from posevote.inference.voting import TestMaps, search_translations
from posevote.model.density import PoseModel, viewpoint_weights
from posevote.model.morph import morphed_positions


@dataclass(frozen=True, kw_only=True, eq=False)
class ProbeSet:
    """Discrete approximations of p(w) (the output of Fig. 2).

    Attributes
    ----------
    azimuth, elevation : ndarray, shape (V,)
        Probed viewpoints, radians.
    inplane : ndarray, shape (A,)
        Probed in-plane angles, radians.
    scale : ndarray, shape (S,)
        Probed scales.
    score : ndarray, shape (V, A, S)
        p(w) at the best translation of each probe.
    translation : ndarray, shape (V, A, S, 2)
        That translation: the reference point ``(u, v)``, pixels.
    box : ndarray, shape (V, 2)
        Object box width and height at each viewpoint, model units.
    """

    azimuth: NDArray[np.float64]
    elevation: NDArray[np.float64]
    inplane: NDArray[np.float64]
    scale: NDArray[np.float64]
    score: NDArray[np.float64]
    translation: NDArray[np.float64]
    box: NDArray[np.float64]

    @cached_property
    def directions(self) -> NDArray[np.float64]:
        """Viewing direction of each probed viewpoint, shape (V, 3)."""
        return viewing_direction(self.azimuth, self.elevation)

    def boxes(self) -> NDArray[np.float64]:
        """Box ``(x, y, w, h)`` of every probe, pixels, shape (V, A, S, 4)."""
        size = np.broadcast_to(self.box[:, None, None, :] * self.scale[None, None, :, None],
                               self.translation.shape)
        return np.concatenate([self.translation - size / 2.0, size], axis=-1)

    @property
    def turntable(self) -> bool:
        """True when every probe has the same elevation (only azimuth varies)."""
        return bool(np.ptp(self.elevation) < 1e-9) if len(self.elevation) else True


def viewpoint_grid(model: PoseModel, *, subdivisions: int = 1, step: float | None = None
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Viewpoints to probe: the training viewpoints, optionally subdivided.

    Because K1 blends neighbouring training views, psi is defined between
    them and may be probed on a finer grid. For turntable models (one
    elevation) ``subdivisions - 1`` azimuths are inserted between each pair of
    neighbouring training azimuths; otherwise the training viewpoints are
    used as they are. With ``step`` (radians), turntable models are probed
    on a regular azimuth grid of that spacing instead, whatever the
    training views: dense, irregular training sets (a car sequence with a
    view every 3 degrees, several cars pooled) then cost a fixed number of
    probes.

    Returns
    -------
    azimuth, elevation : ndarray
        Radians, sorted by azimuth for turntable models.
    """
    if subdivisions < 1:
        raise ValueError(f"subdivisions must be >= 1, got {subdivisions}")
    pairs = np.unique(np.round(np.stack([model.view_azimuth, model.view_elevation], 1), 9), axis=0)
    az, el = pairs[:, 0], pairs[:, 1]
    if step is not None and np.ptp(el) <= 1e-9:
        if not step > 0:
            raise ValueError(f"step must be positive, got {step}")
        n = max(int(round(2 * np.pi / step)), 1)
        regular = np.arange(n, dtype=np.float64) * (2 * np.pi / n)
        return regular, np.full(n, float(el[0]))
    if np.ptp(el) > 1e-9 or subdivisions == 1 or len(az) < 2:
        return np.asarray(az, dtype=np.float64), np.asarray(el, dtype=np.float64)
    az = np.sort(az)
    gaps = np.diff(np.append(az, az[0] + 2 * np.pi))
    steps = np.arange(subdivisions) / subdivisions
    fine = np.mod((az[:, None] + gaps[:, None] * steps[None, :]).ravel(), 2 * np.pi)
    return fine, np.full_like(fine, el[0])


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
    k1 = viewpoint_weights(model, azimuth, elevation, kappa=viewpoint_kappa)
    views = np.flatnonzero(k1 >= k1_cutoff)
    if len(views) == 0:
        views = np.array([int(np.argmax(k1))])
    idx = np.flatnonzero(np.isin(model.view, views))
    w = k1[model.view[idx]] * (model.weight[idx] if use_weights else 1.0)
    total = w.sum()
    xy = model.xy[idx]
    if model.shift is not None and model.view_neighbour is not None:
        xy = morphed_positions(xy, model.shift[idx], model.view[idx], azimuth,
                               model.view_azimuth, model.view_neighbour)
    return ViewpointFeatures(xy=xy, theta=model.theta[idx],
                             weight=w / total if total > 0 else w,
                             box=np.average(model.view_box[views], axis=0, weights=k1[views]))


def probe_poses(
    model: PoseModel,
    maps: TestMaps | Sequence[TestMaps],
    *,
    azimuths: NDArray[np.float64],
    elevations: NDArray[np.float64],
    inplanes: NDArray[np.float64],
    scales: NDArray[np.float64],
    viewpoint_kappa: float,
    use_weights: bool = True,
    k1_cutoff: float = 0.1,
    cell: float | None = None,
    n_candidates: int = 3,
    max_voters: int | None = 200,
    max_features: int | None = None,
    chance_correction: bool = False,
    progress: Callable[[int], None] | None = None,
    n_threads: int = 1,
) -> ProbeSet:
    """Evaluate p(w) at every probe of the grid (Fig. 2).

    Parameters
    ----------
    model : PoseModel
        Training pairs.
    maps : TestMaps or sequence of TestMaps
        The prepared test image: one set of maps for every scale (position
        kernel fixed in image pixels, the paper's K2), or one per scale,
        each prepared from the test features divided by that scale
        (position kernel fixed in object units; see
        :func:`posevote.inference.voting.scaled_features`).
    azimuths, elevations : ndarray, shape (V,)
        Viewpoints to probe, radians.
    inplanes : ndarray, shape (A,)
        In-plane angles, radians.
    scales : ndarray, shape (S,)
        Scales relative to the training images.
    viewpoint_kappa : float
        Concentration of the pose kernel K1.
    use_weights : bool, optional
        Use the features' weights (Eq. 4); all ones otherwise.
    k1_cutoff : float, optional
        Training views whose K1 is below this are left out of a viewpoint.
    cell : float, optional
        Vote grid cell, pixels (default: from the maps' kernel width).
    n_candidates : int, optional
        Vote peaks scored exactly per probe (the best is polished).
    max_voters : int or None, optional
        Training features that vote per probe (an even subset; all count in
        the exact score).
    max_features : int or None, optional
        Training features that take part per probe at all (an even subset;
        see :func:`posevote.inference.voting.search_translations`).
    chance_correction : bool, optional
        With one set of maps per scale, score ``(p - c) / (1 - c)`` where
        ``c`` is that scale's chance level (:attr:`TestMaps.chance`): the
        fraction explained above what random placement explains. Dividing
        the test features by a larger scale packs the clutter tighter in
        object units, so without it large scales win on clutter.
    progress : callable, optional
        Called with 1 after each viewpoint.
    n_threads : int, optional
        Viewpoints probed at once, each in a thread of its own (the search
        kernels release the GIL). Every viewpoint is computed on its own
        and written to its own rows, so the result does not depend on it.

    Returns
    -------
    ProbeSet
    """
    if not (isinstance(n_threads, (int, np.integer)) and n_threads >= 1):
        raise ValueError(f"n_threads must be an integer >= 1, got {n_threads!r}")
    n_v = len(azimuths)
    scales = np.asarray(scales, dtype=np.float64)
    per_scale: list[TestMaps] = [] if isinstance(maps, TestMaps) else list(maps)
    if per_scale and len(per_scale) != len(scales):
        raise ValueError(f"need one TestMaps per scale: {len(per_scale)} for {len(scales)} "
                         "scales")
    score = np.zeros((n_v, len(inplanes), len(scales)))
    translation = np.zeros((n_v, len(inplanes), len(scales), 2))
    box = np.zeros((n_v, 2))

    def probe_view(v: int) -> None:
        """Probe viewpoint ``v``, writing its rows of ``box``, ``score`` and ``translation``."""
        feats = viewpoint_features(model, azimuths[v], elevations[v],
                                   viewpoint_kappa=viewpoint_kappa, use_weights=use_weights,
                                   k1_cutoff=k1_cutoff)
        box[v] = feats.box
        if feats.weight.sum() <= 0:
            return
        if isinstance(maps, TestMaps):
            score[v], translation[v] = search_translations(
                maps, feats.xy, feats.theta, feats.weight, inplanes=inplanes, scales=scales,
                cell=cell, n_candidates=n_candidates, max_voters=max_voters,
                max_features=max_features)
        else:
            for k, (scale_maps, factor) in enumerate(zip(per_scale, scales, strict=True)):
                sc, tr = search_translations(
                    scale_maps, feats.xy, feats.theta, feats.weight, inplanes=inplanes,
                    scales=np.ones(1), cell=cell, n_candidates=n_candidates,
                    max_voters=max_voters, max_features=max_features)
                if chance_correction:
                    c = min(scale_maps.chance, 0.99)
                    sc = np.maximum(sc - c, 0.0) / (1.0 - c)
                score[v, :, k], translation[v, :, k] = sc[:, 0], tr[:, 0] * factor

    if n_threads == 1 or n_v < 2:
        for v in range(n_v):
            probe_view(v)
            if progress is not None:
                progress(1)
    else:
        with ThreadPoolExecutor(max_workers=min(int(n_threads), n_v)) as pool:
            for _ in pool.map(probe_view, range(n_v)):
                if progress is not None:
                    progress(1)
    return ProbeSet(azimuth=np.asarray(azimuths, dtype=float),
                    elevation=np.asarray(elevations, dtype=float),
                    inplane=np.asarray(inplanes, dtype=float), scale=np.asarray(scales, dtype=float),
                    score=score, translation=translation, box=box)
