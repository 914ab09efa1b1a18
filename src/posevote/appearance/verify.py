"""Appearance verification of search candidates, and the nearest training view (beyond the paper).

The voting search of Fig. 2 ranks probes by how many model edges the image
explains there. In a full cluttered frame the best-scoring probe is often a
part of the object at too small a scale, or clutter, while a probe a little
lower in the ranking has the right box. Verification looks at the image
*inside* each of the best candidates' boxes: each box is moved toward the
object by the box regression, its descriptor
(:mod:`posevote.appearance.descriptors`) compared with those of the training
views near the candidate's viewpoint, among the candidates that the
objectness classifier finds most object-like, and the candidate nearest to
a training view wins (:func:`verify_candidates`). :func:`verify` then
searches again inside the winner's box.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from posevote.appearance import AppearanceOptions
from posevote.appearance.descriptors import box_descriptor
from posevote.appearance.model import REGRESSION_STEPS, shift_box
from posevote.features.edges import EdgeFeatures
from posevote.geometry import box_centre, viewing_direction
from posevote.inference.probes import ProbeSet, probe_spacing
from posevote.inference.search import near_scales, probe
from posevote.inference.setup import SearchSetup
from posevote.model.density import PoseModel
from posevote.model.training import AppearanceModel
from posevote.results import Hypothesis
from posevote.scoring.maps import TestMaps, restrict_maps

#: The search again inside the verified box keeps the test edges within the
#: box grown by this fraction of its size on every side: the regressed box
#: can be a little small, and the edges of the object's outline must stay.
VERIFY_MARGIN = 0.25


def verify_candidates(probes: ProbeSet, image: NDArray[np.floating],
                      descriptors: NDArray[np.float32], view_azimuth: NDArray[np.float64],
                      view_elevation: NDArray[np.float64], *, window: tuple[int, int],
                      n_candidates: int, tolerance: float,
                      objectness: NDArray[np.float64] | None = None,
                      regressor: NDArray[np.float64] | None = None,
                      objectness_weight: float = 0.0
                      ) -> tuple[tuple[int, int, int], float, tuple[float, ...]] | None:
    """The search candidate whose crop looks most like a training view near its viewpoint.

    Parameters
    ----------
    probes : ProbeSet
        The search's probes.
    image : ndarray, shape (H, W)
        The grey test image.
    descriptors : ndarray, shape (K, D)
        Descriptor of each training view (:func:`box_descriptor`).
    view_azimuth, view_elevation : ndarray, shape (K,)
        Training viewpoints, radians.
    window : (height, width)
        Descriptor window.
    n_candidates : int
        How many of the best probes (highest p(w)) are verified.
    tolerance : float
        A candidate is compared with the training views within this angle of
        its viewpoint, radians.
    objectness : ndarray, shape (D + 1,), optional
        Classifier of :func:`train_objectness`, weighed in by
        ``objectness_weight``.
    regressor : ndarray, shape (B, 4, D + 1), optional
        Box regressions (:func:`train_box_regression`); with them, each
        candidate's box is first regressed
        (:func:`regress_described`) and the regressed box's descriptor is
        compared.
    objectness_weight : float, optional
        With ``objectness``, a candidate's distance to its nearest training
        view minus this times the classifier's score of the compared
        descriptor decides (0: the distance alone).

    Returns
    -------
    ((viewpoint, inplane, scale), distance, box) or None
        Indices of the winning probe, its (weighted) descriptor distance and the box
        that was compared (the probe's, or its regressed box); None if no
        candidate has a descriptor (boxes outside the image) or a training
        view within ``tolerance``.
    """
    order = np.argsort(-probes.score, axis=None, kind="stable")[:n_candidates]
    train_dirs = viewing_direction(view_azimuth, view_elevation)
    cos_tol = np.cos(tolerance)
    found: list[tuple[tuple[int, int, int], NDArray[np.bool_], NDArray[np.float32]]] = []
    boxes = probes.boxes()
    for flat in order:
        v, a, s = (int(i) for i in np.unravel_index(flat, probes.score.shape))
        if probes.score[v, a, s] <= 0:
            break
        near = train_dirs @ probes.directions[v] >= cos_tol
        if not near.any():
            continue
        d = box_descriptor(image, boxes[v, a, s], window)
        if d is not None:
            found.append(((v, a, s), near, d))
    if not found:
        return None
    compared: list[tuple[tuple[int, int, int], NDArray[np.bool_], tuple[float, ...]]] = []
    described = []
    for index, near, d in found:
        v, a, s = index
        box = tuple(float(b) for b in boxes[v, a, s])
        if regressor is not None:
            moved, regressed = regress_described(image, box, d, regressor,
                                                 float(probes.azimuth[v]), window=window)
            if regressed is not None:
                box, d = moved, regressed
        compared.append((index, near, box))
        described.append(d)
    # All candidates against all training views in one product: gathering each
    # viewpoint's near views cost more than the products themselves.
    d_all = np.array(described, dtype=np.float32)
    sq_all = (np.einsum("ij,ij->i", descriptors, descriptors)[None, :]
              + np.einsum("ij,ij->i", d_all, d_all)[:, None] - 2.0 * (d_all @ descriptors.T))
    if objectness is not None and objectness_weight:
        looks_all = d_all.astype(np.float64) @ objectness[:-1] + objectness[-1]
    best: tuple[tuple[int, int, int], float, tuple[float, ...]] | None = None
    for k, (index, near, box) in enumerate(compared):
        # The nearest view by the product's expansion, its distance exactly
        # (the expansion cancels in float32 near a match).
        views = np.flatnonzero(near)
        nearest = int(views[np.argmin(sq_all[k, views])])
        dist = float(np.linalg.norm(d_all[k] - descriptors[nearest]))
        if objectness is not None and objectness_weight:
            dist -= objectness_weight * float(looks_all[k])
        if best is None or dist < best[1]:
            best = (index, dist, box)
    return best


def regress_box(image: NDArray[np.floating], box: Sequence[float], regressor: NDArray[np.float64],
                azimuth: float, *, window: tuple[int, int], steps: int = REGRESSION_STEPS
                ) -> tuple[float, float, float, float]:
    """Move ``box`` toward the object by the regression of its azimuth range, ``steps`` times.

    A box whose descriptor cannot be computed (less than 8x8 pixels in the
    image) stays where it is.
    """
    return regress_described(image, box, box_descriptor(image, box, window), regressor, azimuth,
                             window=window, steps=steps)[0]


def regress_described(image: NDArray[np.floating], box: Sequence[float],
                      descriptor: NDArray[np.float32] | None, regressor: NDArray[np.float64],
                      azimuth: float, *, window: tuple[int, int], steps: int = REGRESSION_STEPS
                      ) -> tuple[tuple[float, float, float, float], NDArray[np.float32] | None]:
    """:func:`regress_box` from the box's ``descriptor``; also returns the moved box's.

    Each step describes the moved box once: ``steps`` descriptors in all,
    the last one the returned box's. A move onto a box that cannot be
    described (less than 8x8 pixels in the image) is not taken; the
    returned descriptor is None only when ``descriptor`` is.
    """
    bins = regressor.shape[0]
    coef = regressor[int(np.mod(azimuth, 2.0 * np.pi) // (2.0 * np.pi / bins)) % bins]
    x, y, w, h = (float(b) for b in box)
    out, d = (x, y, w, h), descriptor
    for _ in range(steps):
        if d is None:
            break
        moved = shift_box(out, coef[:, :-1] @ d + coef[:, -1])
        d_moved = box_descriptor(image, moved, window)
        if d_moved is None:
            break
        out, d = moved, d_moved
    return out, d


def views_within(view_directions: NDArray[np.float64], direction: NDArray[np.float64],
                 window: float) -> NDArray[np.intp]:
    """Indices of the views whose viewing direction lies within ``window`` radians of ``direction``."""
    return np.flatnonzero(view_directions @ direction >= np.cos(window) - 1e-12)


def nearest_view(descriptor: NDArray[np.float32], descriptors: NDArray[np.float32],
                 view_directions: NDArray[np.float64], direction: NDArray[np.float64], *,
                 window: float) -> int | None:
    """The training view whose descriptor is nearest, among those within ``window`` radians.

    Returns its index, or None when no training view is that near ``direction``.
    """
    near = views_within(view_directions, direction, window)
    if len(near) == 0:
        return None
    sq = np.einsum("ij,ij->i", descriptors[near], descriptors[near]) - 2.0 * (
        descriptors[near] @ descriptor)
    return int(near[np.argmin(sq)])


def box_grid(box: Sequence[float], fraction: float) -> NDArray[np.float64]:
    """``box`` and its 26 neighbours: shifted by ``-fraction``, 0 or ``+fraction`` of its
    width and height and scaled by ``1 - fraction``, 1 or ``1 + fraction`` about its centre.

    Returns
    -------
    ndarray, shape (27, 4)
        Boxes ``(x, y, w, h)``; row 13 is ``box`` itself.
    """
    x, y, w, h = (float(b) for b in box)
    steps = (-fraction, 0.0, fraction)
    out = []
    for dx in steps:
        for dy in steps:
            for ds in steps:
                ww, hh = w * (1.0 + ds), h * (1.0 + ds)
                cx, cy = x + 0.5 * w + dx * w, y + 0.5 * h + dy * h
                out.append((cx - 0.5 * ww, cy - 0.5 * hh, ww, hh))
    return np.array(out)


def medoid_view(views: Sequence[int], view_directions: NDArray[np.float64]) -> int:
    """The view of ``views`` whose summed angle to the others' viewing directions is least.

    Views may repeat (each counts once per occurrence); ties go to the first.
    """
    idx = np.asarray(views, dtype=np.intp)
    dirs = view_directions[idx]
    angles = np.arccos(np.clip(dirs @ dirs.T, -1.0, 1.0))
    return int(idx[np.argmin(angles.sum(axis=1))])


def jittered_nearest_view(image: NDArray[np.floating], box: Sequence[float],
                          descriptors: NDArray[np.float32], view_directions: NDArray[np.float64],
                          direction: NDArray[np.float64], *, window: float,
                          descriptor_window: tuple[int, int], fraction: float) -> int | None:
    """:func:`nearest_view` of ``box`` and of its :func:`box_grid`, their :func:`medoid_view`.

    Beyond the paper: the nearest training descriptor of one box jumps
    between views when the box is a few pixels off; the medoid of the
    nearest views of 27 boxes around it does not.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey test image.
    box : (x, y, w, h)
        The estimate's box.
    descriptors, view_directions, direction, window
        As in :func:`nearest_view`.
    descriptor_window : (int, int)
        :func:`window_shape` of the model.
    fraction : float
        Jitter of :func:`box_grid`.

    Returns
    -------
    int or None
        The view's index; None when no training view lies within ``window``
        or no jittered box can be described.
    """
    near = views_within(view_directions, direction, window)
    described = [box_descriptor(image, b, descriptor_window) for b in box_grid(box, fraction)]
    found = np.array([d for d in described if d is not None])
    if len(near) == 0 or len(found) == 0:
        return None
    ref = descriptors[near]
    sq = np.einsum("ij,ij->i", ref, ref)[None, :] - 2.0 * (found @ ref.T)
    return medoid_view(near[np.argmin(sq, axis=1)].tolist(), view_directions)


def verify(probes: ProbeSet, image: NDArray[np.floating], features: EdgeFeatures,
           maps: TestMaps | list[TestMaps], model: PoseModel, appearance: AppearanceModel,
           options: AppearanceOptions, setup: SearchSetup
           ) -> tuple[EdgeFeatures, TestMaps | list[TestMaps | None], ProbeSet,
                      tuple[float, float, float, float]] | None:
    """Verify the best probes by appearance and search again in the winner's box.

    Parameters
    ----------
    probes : ProbeSet
        The first search's probes.
    image : ndarray, shape (H, W)
        The grey test image.
    features : EdgeFeatures
        Its edge features.
    maps : TestMaps or list of TestMaps
        The search maps the probes came from.
    model : PoseModel
        The searched model.
    appearance : AppearanceModel
        The training views' descriptors, classifier and box regressions.
    options : AppearanceOptions
    setup : SearchSetup

    Returns
    -------
    (features, maps, probes, box) or None
        The test features inside the winner's box (grown by
        :data:`VERIFY_MARGIN`), the maps restricted to it, the probes of the
        search again near the winner's viewpoint, and the winner's regressed
        box; None when no candidate could be verified.
    """
    if appearance.regressor is None:
        raise ValueError("the appearance verification needs the box regression, which this "
                         "model lacks; retrain it")
    found = verify_candidates(probes, image, appearance.descriptors, model.view_azimuth,
                              model.view_elevation, window=appearance.window,
                              n_candidates=options.candidates,
                              tolerance=probe_spacing(probes) if options.tolerance_deg is None
                              else np.radians(options.tolerance_deg),
                              objectness=appearance.objectness,
                              regressor=appearance.regressor,
                              objectness_weight=options.objectness_weight)
    if found is None:
        return None
    (v, a, s), _, box = found
    # The winner was judged on its regressed box: search again inside that.
    size = np.array(box[2:])
    centre = np.asarray(box_centre(box), dtype=np.float64)
    half = size * (0.5 + VERIFY_MARGIN)
    keep = np.all(np.abs(features.xy - centre) <= half, axis=1)
    if not keep.any():
        return None
    x, y, w, h = box
    # The regressed box's height tells the scale: only the scales near it are
    # searched again (and their maps restricted).
    near = Hypothesis(azimuth=float(probes.azimuth[v]), elevation=float(probes.elevation[v]),
                      inplane=float(probes.inplane[a]), scale=float(h / probes.box[v, 1]),
                      position=(float(centre[0]), float(centre[1])), box=(x, y, w, h),
                      score=float(probes.score[v, a, s]), refined=False)
    inside: TestMaps | list[TestMaps | None]
    if isinstance(maps, TestMaps):
        inside = restrict_maps(maps, centre - half, centre + half)
    else:
        kept = set(near_scales(probes.scale, near.scale, setup.options).tolist())
        inside = [restrict_maps(m, (centre - half) / f, (centre + half) / f) if k in kept
                  else None for k, (m, f) in enumerate(zip(maps, probes.scale, strict=True))]
    again = probe(model, inside, setup, near=near)
    return features.select(keep), inside, again, (x, y, w, h)
