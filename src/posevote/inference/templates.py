"""The search's best probes re-ranked by how well the image matches the object's grey levels.

Beyond the paper (``SearchOptions.rerank = "template"``). Under each of the
best :data:`TEMPLATE_CANDIDATES` probes, the test image is sampled in the
frame of the nearest training view's template
(:mod:`posevote.model.templates`) and compared with it by normalised
cross-correlation in :data:`TILES` x :data:`TILES` tiles of the template's
mask; the mean of the best :data:`KEEP` of the tiles (a hidden part of the
object loses only its own tiles) multiplies the probe's score. Every other
probe is multiplied by the lowest of those factors, so that the rest keep
their order below them, as in the coverage re-ranking
(:mod:`posevote.inference.coverage`).
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
from numpy.typing import NDArray

from posevote.geometry import viewing_direction
from posevote.inference.search import ProbeSet
from posevote.model.density import PoseModel
from posevote.model.templates import TEMPLATE_BLUR, TEMPLATE_SIDE, template_frame

#: Probes re-ranked (docs/DEFAULTS.md, "Template re-ranking").
TEMPLATE_CANDIDATES = 300
#: Tiles across the mask's box, the share of them kept (the best ones), and
#: the fewest template pixels a tile needs to count.
TILES = 4
KEEP = 0.5
MIN_TILE_PIXELS = 12
#: The factor of a probe whose image does not correlate with the template.
_FLOOR = 0.01


def _tiles(template: NDArray[np.float16]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """The template's valid pixels (flat indices) and the tile of each."""
    valid = np.isfinite(template)
    rows, cols = np.nonzero(valid)
    if rows.size == 0:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    r0, r1 = rows.min(), rows.max() + 1
    c0, c1 = cols.min(), cols.max() + 1
    tile = ((rows - r0) * TILES // (r1 - r0)) * TILES + (cols - c0) * TILES // (c1 - c0)
    return np.flatnonzero(valid), tile


def tile_correlation(patch: NDArray[np.floating], template: NDArray[np.floating],
                     pixels: NDArray[np.intp], tile: NDArray[np.intp]) -> float:
    """The mean of the best ``KEEP`` tiles' normalised cross-correlations.

    Parameters
    ----------
    patch : ndarray, shape (T, T)
        The test image sampled in the template's frame.
    template : ndarray, shape (T, T)
        The view's template.
    pixels, tile : ndarray of int
        The template's valid pixels (flat) and their tiles (:func:`_tiles`).

    Returns
    -------
    float
        In [-1, 1]; 0 when no tile has :data:`MIN_TILE_PIXELS` pixels.
    """
    x = patch.ravel()[pixels].astype(np.float64)
    y = template.ravel()[pixels].astype(np.float64)
    n_tiles = TILES * TILES
    sums = np.stack([np.bincount(tile, w, n_tiles).astype(np.float64)
                     for w in (np.ones_like(x), x, y, x * x, y * y, x * y)])
    full = sums[0] >= MIN_TILE_PIXELS
    if not full.any():
        return 0.0
    n, sx, sy, sxx, syy, sxy = sums[:, full]
    cov = sxy - sx * sy / n
    var = np.maximum(sxx - sx * sx / n, 0.0) * np.maximum(syy - sy * sy / n, 0.0)
    # A flat tile (no texture on either side) says nothing: it correlates 0.
    ncc = np.where(var > 1e-12, cov / np.sqrt(np.maximum(var, 1e-24)), 0.0)
    best = np.sort(ncc)[::-1]
    return float(best[:max(1, int(round(len(best) * KEEP)))].mean())


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
        If the model has no templates (trained by a posevote without them).
    """
    if model.view_template is None or model.view_template_cell is None:
        raise ValueError("SearchOptions.rerank='template' needs a model with the views' "
                         "templates; fit it again")
    score = probes.score
    best = np.argsort(-score.ravel(), kind="stable")[:TEMPLATE_CANDIDATES]
    best = best[score.ravel()[best] > 0]
    if len(best) == 0:
        return probes
    views = viewing_direction(model.view_azimuth, model.view_elevation)
    cell = float(np.median(model.view_template_cell))
    grey = np.asarray(image, dtype=np.float32)
    blurred: dict[int, NDArray[np.floating]] = {}
    tiles: dict[int, tuple[NDArray[np.intp], NDArray[np.intp]]] = {}
    size = (TEMPLATE_SIDE, TEMPLATE_SIDE)
    found = np.empty(len(best))
    for n, flat in enumerate(best):
        v, a, k = (int(i) for i in np.unravel_index(flat, score.shape))
        view = int(np.argmax(views @ probes.directions[v]))
        s = float(probes.scale[k])
        if k not in blurred:
            # Blurred as the templates were, in template pixels at this scale.
            blurred[k] = np.asarray(cv2.GaussianBlur(grey, (0, 0), TEMPLATE_BLUR * cell * s),
                                    dtype=np.float32)
        if view not in tiles:
            tiles[view] = _tiles(model.view_template[view])
        frame = template_frame(probes.translation[v, a, k],
                               s * float(model.view_template_cell[view]), float(probes.inplane[a]))
        patch = np.asarray(cv2.warpAffine(blurred[k], frame, size,
                                          flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                          borderMode=cv2.BORDER_REFLECT), dtype=np.float32)
        found[n] = tile_correlation(patch, model.view_template[view], *tiles[view])
    found = np.maximum(found, _FLOOR)
    factor = np.full(score.size, float(found.min()))
    factor[best] = found
    return replace(probes, score=np.where(score > 0, score * factor.reshape(score.shape), score))
