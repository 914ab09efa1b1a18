"""The search's best probes re-ranked by how well the image matches the object's grey levels.

Beyond the paper (``TemplateOptions.rerank``). Under each of the
best :data:`TEMPLATE_CANDIDATES` probes, and of every further probe whose edge
score exceeds the best of their products (those that could still come first:
a product never exceeds its edge score), the test image is sampled at the
places of the nearest training view's template pixels
(:mod:`posevote.templates.model`) and compared with them by normalised
cross-correlation in :data:`TILES` x :data:`TILES` tiles of the template's
mask; the mean of the best :data:`KEEP` of the tiles (a hidden part of the
object loses only its own tiles) multiplies the probe's score. Every other
probe is multiplied by the lowest of those factors, so that the rest keep
their order below them, as in the coverage re-ranking
(:mod:`posevote.inference.coverage`).

:func:`correlation_weights` weighs the poses a refinement compares the same
way (``TemplateOptions.weigh``), and :func:`gradient_similarity` compares a
pose's image with its nearest template by their gradients instead (HOG
blocks), for the half-turn check over the sphere
(:mod:`posevote.templates.halfturn`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import cv2
import numba
import numpy as np
from numpy.typing import NDArray

from posevote.features.hog import HOG_CELL, hog
from posevote.geometry import viewing_direction
from posevote.inference.probes import ProbeSet
from posevote.model.density import PoseModel
from posevote.results import Hypothesis
from posevote.templates.model import TEMPLATE_BLUR, in_template, template_frame

#: Probes re-ranked at least; beyond them, every probe whose edge score beats the
#: best product (docs/history/DEFAULTS.md, "Template re-ranking").
TEMPLATE_CANDIDATES = 300
#: Tiles across the mask's box, the share of them kept (the best ones), and
#: the fewest template pixels a tile needs to count.
TILES = 4
KEEP = 0.5
MIN_TILE_PIXELS = 12
#: The factor of a pose whose image does not correlate with the template.
CORRELATION_FLOOR = 0.01


@dataclass(frozen=True, kw_only=True, eq=False)
class TemplatePixels:
    """The valid pixels of one template.

    Attributes
    ----------
    xy : ndarray, shape (P, 2)
        Their template coordinates ``(column, row)``.
    tile : ndarray of int, shape (P,)
        The tile of each, ``row_tile * TILES + column_tile`` over the pixels' box.
    value : ndarray, shape (P,)
        Their grey levels.
    """

    xy: NDArray[np.float64]
    tile: NDArray[np.int64]
    value: NDArray[np.float64]


def template_pixels(template: NDArray[np.floating]) -> TemplatePixels:
    """The template's finite pixels, their tiles and values."""
    rows, cols = np.nonzero(np.isfinite(template))
    if rows.size == 0:
        return TemplatePixels(xy=np.zeros((0, 2)), tile=np.zeros(0, dtype=np.int64),
                              value=np.zeros(0))
    r0, r1 = rows.min(), rows.max() + 1
    c0, c1 = cols.min(), cols.max() + 1
    tile = ((rows - r0) * TILES // (r1 - r0)) * TILES + (cols - c0) * TILES // (c1 - c0)
    return TemplatePixels(xy=np.column_stack([cols, rows]).astype(np.float64),
                          tile=tile.astype(np.int64),
                          value=template[rows, cols].astype(np.float64))


def sample_bilinear(image: NDArray[np.floating], xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """``image`` at the points ``xy`` (``(u, v)`` pixels), bilinear, the border extended."""
    h, w = image.shape
    u = np.clip(xy[:, 0], 0.0, w - 1.0)
    v = np.clip(xy[:, 1], 0.0, h - 1.0)
    c0 = np.minimum(u.astype(np.int64), w - 2) if w > 1 else np.zeros(len(u), np.int64)
    r0 = np.minimum(v.astype(np.int64), h - 2) if h > 1 else np.zeros(len(v), np.int64)
    fu, fv = u - c0, v - r0
    c1, r1 = np.minimum(c0 + 1, w - 1), np.minimum(r0 + 1, h - 1)
    img = image.astype(np.float64)
    return ((1 - fv) * ((1 - fu) * img[r0, c0] + fu * img[r0, c1])
            + fv * ((1 - fu) * img[r1, c0] + fu * img[r1, c1]))


def tile_correlation(x: NDArray[np.floating], y: NDArray[np.floating],
                     tile: NDArray[np.int64]) -> float:
    """The mean of the best ``KEEP`` tiles' normalised cross-correlations (numpy).

    Parameters
    ----------
    x : ndarray, shape (P,)
        The test image at the template's pixels.
    y : ndarray, shape (P,)
        The template's grey levels there.
    tile : ndarray of int, shape (P,)
        The tile of each pixel (:func:`template_pixels`).

    Returns
    -------
    float
        In [-1, 1]; 0 when no tile has :data:`MIN_TILE_PIXELS` pixels. A flat
        tile (no texture on either side) correlates 0.
    """
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    n_tiles = TILES * TILES
    sums = np.stack([np.bincount(tile, w, n_tiles).astype(np.float64)
                     for w in (np.ones_like(x), x, y, x * x, y * y, x * y)])
    full = sums[0] >= MIN_TILE_PIXELS
    if not full.any():
        return 0.0
    n, sx, sy, sxx, syy, sxy = sums[:, full]
    cov = sxy - sx * sy / n
    var = np.maximum(sxx - sx * sx / n, 0.0) * np.maximum(syy - sy * sy / n, 0.0)
    ncc = np.where(var > 1e-12, cov / np.sqrt(np.maximum(var, 1e-24)), 0.0)
    best = np.sort(ncc)[::-1]
    return float(best[:max(1, int(round(len(best) * KEEP)))].mean())


# One pass over each candidate's template pixels where numpy sampled, then
# binned six sums; tile_correlation and sample_bilinear are its reference.
@numba.njit(cache=True, nogil=True)
def _correlations(img, frames, view_of, start, xy, tile, value, n_tiles, keep, min_pixels,
                  out):  # pragma: no cover - compiled
    """For each candidate ``n``: ``img`` sampled at the pixels of view ``view_of[n]``
    (``start[v]:start[v + 1]`` of ``xy``, ``tile``, ``value``) mapped by ``frames[n]``,
    correlated tile by tile, the best ``keep`` share averaged."""
    h, w = img.shape
    sums = np.zeros((n_tiles, 6))
    ncc = np.zeros(n_tiles)
    for n in range(frames.shape[0]):
        f = frames[n]
        sums[:, :] = 0.0
        for p in range(start[view_of[n]], start[view_of[n] + 1]):
            u = f[0, 0] * xy[p, 0] + f[0, 1] * xy[p, 1] + f[0, 2]
            v = f[1, 0] * xy[p, 0] + f[1, 1] * xy[p, 1] + f[1, 2]
            u = min(max(u, 0.0), w - 1.0)
            v = min(max(v, 0.0), h - 1.0)
            c0 = min(int(u), w - 2) if w > 1 else 0
            r0 = min(int(v), h - 2) if h > 1 else 0
            c1, r1 = min(c0 + 1, w - 1), min(r0 + 1, h - 1)
            fu, fv = u - c0, v - r0
            s = ((1 - fv) * ((1 - fu) * img[r0, c0] + fu * img[r0, c1])
                 + fv * ((1 - fu) * img[r1, c0] + fu * img[r1, c1]))
            t, y = tile[p], value[p]
            sums[t, 0] += 1.0
            sums[t, 1] += s
            sums[t, 2] += y
            sums[t, 3] += s * s
            sums[t, 4] += y * y
            sums[t, 5] += s * y
        m = 0
        for t in range(n_tiles):
            k = sums[t, 0]
            if k < min_pixels:
                continue
            cov = sums[t, 5] - sums[t, 1] * sums[t, 2] / k
            var = (max(sums[t, 3] - sums[t, 1] * sums[t, 1] / k, 0.0)
                   * max(sums[t, 4] - sums[t, 2] * sums[t, 2] / k, 0.0))
            ncc[m] = cov / np.sqrt(var) if var > 1e-12 else 0.0
            m += 1
        if m == 0:
            out[n] = 0.0
            continue
        best = -np.sort(-ncc[:m])
        kept = max(1, int(np.round(m * keep)))
        out[n] = best[:kept].mean()


def correlations(image: NDArray[np.float32], frames: NDArray[np.float64],
                 view_of: NDArray[np.int64], pixels: list[TemplatePixels]) -> NDArray[np.float64]:
    """Each candidate's tiled correlation (:func:`tile_correlation`), compiled.

    Parameters
    ----------
    image : ndarray of float32, shape (H, W)
        The test image, blurred for the candidates' scale.
    frames : ndarray, shape (N, 2, 3)
        Each candidate's map from template pixels to image pixels
        (:func:`posevote.templates.model.template_frame`).
    view_of : ndarray of int, shape (N,)
        The index into ``pixels`` of each candidate's template.
    pixels : list of TemplatePixels

    Returns
    -------
    ndarray, shape (N,)
    """
    start = np.concatenate([[0], np.cumsum([len(p.tile) for p in pixels])]).astype(np.int64)
    out = np.empty(len(frames))
    _correlations(np.ascontiguousarray(image, dtype=np.float32),
                  np.asarray(frames, dtype=np.float64), np.asarray(view_of, dtype=np.int64), start,
                  np.vstack([p.xy for p in pixels] + [np.zeros((0, 2))]),
                  np.concatenate([p.tile for p in pixels] + [np.zeros(0, np.int64)]),
                  np.concatenate([p.value for p in pixels] + [np.zeros(0)]),
                  TILES * TILES, KEEP, float(MIN_TILE_PIXELS), out)
    return out


def nearest_views(model: PoseModel, azimuth: NDArray[np.float64],
                  elevation: NDArray[np.float64]) -> NDArray[np.intp]:
    """The training view nearest each viewpoint (arrays of N), by viewing direction."""
    # Per distinct viewpoint: thousands of candidates share a few hundred.
    pairs, back = np.unique(np.column_stack([azimuth, elevation]), axis=0, return_inverse=True)
    return np.argmax(viewing_direction(pairs[:, 0], pairs[:, 1]) @ viewing_direction(
        model.view_azimuth, model.view_elevation).T, axis=1)[back.ravel()]


def pose_correlations(model: PoseModel, image: NDArray[np.floating],
                      azimuth: NDArray[np.float64], elevation: NDArray[np.float64],
                      inplane: NDArray[np.float64], scale: NDArray[np.float64],
                      position: NDArray[np.float64]) -> NDArray[np.float64]:
    """The tiled correlation of the image with the nearest training view's template under
    each pose (arrays of N; ``position`` (N, 2), the reference point in pixels).

    Raises
    ------
    ValueError
        If the model has no templates (trained by a posevote without them).
    """
    if model.view_template is None or model.view_template_cell is None:
        raise ValueError("the template steps need the views' templates, learnt when the "
                         "model is fitted with them; fit (or retrain) with "
                         "templates=TemplateOptions()")
    nearest = nearest_views(model, azimuth, elevation)
    views, view_of = np.unique(nearest, return_inverse=True)
    view_of = view_of.ravel()
    pixels = [template_pixels(model.view_template[view]) for view in views]
    cell = float(np.median(model.view_template_cell))
    grey = np.asarray(image, dtype=np.float32)
    frames = template_frame(position, scale * model.view_template_cell[nearest], inplane)
    out = np.empty(len(frames))
    # One scale at a time: one blurred copy of the image in memory.
    for f in np.unique(scale):
        at = np.flatnonzero(scale == f)
        # Blurred as the templates were, in template pixels at this scale.
        blurred = np.asarray(cv2.GaussianBlur(grey, (0, 0), TEMPLATE_BLUR * cell * float(f)),
                             dtype=np.float32)
        out[at] = correlations(blurred, frames[at], view_of[at], pixels)
    return out


def correlation_weights(model: PoseModel, image: NDArray[np.floating]
                        ) -> Callable[[Sequence[Hypothesis]], NDArray[np.float64]]:
    """What weighs poses by the object's grey levels: each pose's :func:`pose_correlations`,
    floored at :data:`CORRELATION_FLOOR` (a pose that does not correlate keeps a share
    of its score, so that poses still compare by their edges)."""

    def weigh(hyps: Sequence[Hypothesis]) -> NDArray[np.float64]:
        found = pose_correlations(model, image, *(np.array([getattr(h, name) for h in hyps])
                                                  for name in ("azimuth", "elevation",
                                                               "inplane", "scale", "position")))
        return np.maximum(found, CORRELATION_FLOOR)
    return weigh


def gradient_similarity(model: PoseModel, image: NDArray[np.floating], hypothesis: Hypothesis
                        ) -> float:
    """How alike the image's gradients and the nearest training view's template's are
    under a pose.

    The image is resampled into the template's frame (:func:`template_frame`)
    and both are described by HOG (:func:`posevote.features.hog.hog`,
    the template's background filled with the image's own pixels); the
    result is the mean cosine of their blocks that lie mostly on the
    template's mask. Histograms of orientations pooled over cells tolerate
    the pixel or two by which a pose between views misplaces a detail that
    a grey-level correlation reads as a mismatch.

    Parameters
    ----------
    model : PoseModel
        With templates.
    image : ndarray, shape (H, W)
        The grey test image.
    hypothesis : Hypothesis
        The pose, in image pixels.

    Returns
    -------
    float
        In [0, 1]; 0 where no block lies on the mask.
    """
    if model.view_template is None or model.view_template_cell is None:
        raise ValueError("gradient_similarity needs the views' templates (fit with "
                         "templates=TemplateOptions())")
    view = int(nearest_views(model, np.array([hypothesis.azimuth]),
                             np.array([hypothesis.elevation]))[0])
    template = np.asarray(model.view_template[view], dtype=np.float32)
    frame = template_frame(np.asarray(hypothesis.position, dtype=np.float64),
                           hypothesis.scale * model.view_template_cell[view], hypothesis.inplane)
    side = template.shape[0]
    crop = in_template(image, frame)
    mask = np.isfinite(template)
    # The background scores as the image's own: only the object's blocks differ.
    filled = np.where(mask, template, crop)
    blocks = side // HOG_CELL - 1
    described = [hog(x).reshape(blocks, blocks, -1) for x in (crop, filled)]
    cells = cv2.resize(mask.astype(np.float32), (side // HOG_CELL, side // HOG_CELL),
                       interpolation=cv2.INTER_AREA)
    on_mask = (cells[:-1, :-1] + cells[1:, :-1] + cells[:-1, 1:] + cells[1:, 1:]) > 2.0
    if not on_mask.any():
        return 0.0
    a, b = (d[on_mask].astype(np.float64) for d in described)
    norms = np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1)
    return float(np.mean(np.sum(a * b, axis=1) / np.maximum(norms, 1e-12)))


def rerank_by_template(probes: ProbeSet, model: PoseModel, image: NDArray[np.floating]
                       ) -> ProbeSet:
    """Multiply the best probes' scores by their template correlation.

    Parameters
    ----------
    probes : ProbeSet
        The search's probes.
    model : PoseModel
        With ``view_template`` and ``view_template_cell``.
    image : ndarray, shape (H, W)
        The grey test image.

    Returns
    -------
    ProbeSet
        The same probes with re-ranked scores.

    Raises
    ------
    ValueError
        If the model has no templates (:func:`pose_correlations`) and a probe scores.
    """
    score = probes.score
    flat = score.ravel()
    order = np.argsort(-flat, kind="stable")
    order = order[flat[order] > 0]
    if len(order) == 0:
        return probes

    def correlate(chosen: NDArray[np.intp]) -> NDArray[np.float64]:
        v, a, k = np.unravel_index(chosen, score.shape)
        found = pose_correlations(model, image, probes.azimuth[v], probes.elevation[v],
                                  probes.inplane[a], probes.scale[k],
                                  probes.translation[v, a, k])
        return np.maximum(found, CORRELATION_FLOOR)

    best, rest = order[:TEMPLATE_CANDIDATES], order[TEMPLATE_CANDIDATES:]
    found = correlate(best)
    # A probe's product cannot exceed its edge score: every one scoring above the
    # best product so far could still come first, however deep in the ranking.
    contender = rest[flat[rest] > float(np.max(flat[best] * found))]
    if len(contender):
        best, found = np.concatenate([best, contender]), np.concatenate(
            [found, correlate(contender)])
    factor = np.full(score.size, float(found.min()))
    factor[best] = found
    return replace(probes, score=np.where(score > 0, score * factor.reshape(score.shape), score))
