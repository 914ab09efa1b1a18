"""A mode's score against its own frame's background (the ``contrast`` step).

The same pose is placed over the rest of the frame, away from the mode's box,
and scored there on the same maps; the mode's contrast is its score over the
spread of those scores, less what the best of the frame's places for such a
box would reach by chance. A cluttered frame scores every placement high and
spread, a plain one low, and a small box has more places in a large frame
than a large one: the contrast reads the same in all of them, where the score
alone rewards the clutter (docs/history/TRUST.md).
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from posevote.geometry import box_iou
from posevote.model.density import PoseModel
from posevote.results import Hypothesis
from posevote.scoring.maps import TestMaps
from posevote.scoring.score import features_at, gather_score

#: Placements whose box overlaps the mode's by more than this IoU see the object itself.
MAX_OVERLAP = 0.1
#: At least this many placements, the least overlapping, however small the frame.
MIN_PLACEMENTS = 16
#: At most about this many placements (their step widens on a large frame).
MAX_PLACEMENTS = 20_000
#: Added to the spread: a blank background (every placement 0) gives a finite contrast.
SPREAD_FLOOR = 0.002


@numba.njit(cache=True, nogil=True)
def _scores_at(density, frame, xy, theta, weight, alpha, scale, us, vs
               ):  # pragma: no cover - compiled
    out = np.empty(us.shape[0])
    for k in range(us.shape[0]):
        out[k] = gather_score(density, frame, xy, theta, weight, alpha, scale, us[k], vs[k])
    return out


def placements(hypothesis: Hypothesis, shape: tuple[int, int]
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Where the mode's pose is placed: its reference point on a grid over the frame, a
    quarter of its box's smaller side apart, its box overlapping the mode's by at most
    :data:`MAX_OVERLAP` (the :data:`MIN_PLACEMENTS` least overlapping, where fewer do).

    Returns
    -------
    u, v : ndarray
        The placements' reference-point positions, pixels.
    """
    h, w = shape
    _, _, bw, bh = hypothesis.box
    step = max(4.0, min(bw, bh) / 4.0, math.sqrt(h * w / MAX_PLACEMENTS))
    u, v = np.meshgrid(np.arange(step / 2.0, w, step), np.arange(step / 2.0, h, step))
    u, v = u.ravel(), v.ravel()
    u0, v0 = hypothesis.position
    x, y = hypothesis.box[:2]
    placed = np.stack([x + u - u0, y + v - v0, np.full_like(u, bw), np.full_like(u, bh)], axis=1)
    iou = np.asarray(box_iou(placed, np.asarray(hypothesis.box, dtype=np.float64)))
    keep = np.flatnonzero(iou <= MAX_OVERLAP)
    if len(keep) < MIN_PLACEMENTS:
        keep = np.argsort(iou, kind="stable")[:MIN_PLACEMENTS]
    return u[keep], v[keep]


def background_scores(hypothesis: Hypothesis, model: PoseModel, maps: TestMaps,
                      shape: tuple[int, int], **score_options: Any) -> NDArray[np.float64]:
    """The exact p(w) of the mode's pose (viewpoint, in-plane angle, scale) at each of its
    :func:`placements`, on ``maps`` (``score_options``: :func:`~posevote.scoring.score.
    score_options`)."""
    u, v = placements(hypothesis, shape)
    feats = features_at(hypothesis, model, max_features=None, **score_options)
    if feats.weight.sum() <= 0 or not len(u):
        return np.zeros(len(u))
    return np.asarray(_scores_at(maps.density, maps.frame, feats.xy, feats.theta, feats.weight,
                                 float(hypothesis.inplane), float(hypothesis.scale),
                                 np.ascontiguousarray(u), np.ascontiguousarray(v)))


def mode_contrast(hypothesis: Hypothesis, model: PoseModel, maps: TestMaps,
                  shape: tuple[int, int], **score_options: Any) -> float:
    """The mode's score over the spread of what its pose scores elsewhere, less what the
    best of the frame's many places would reach by chance.

    With ``z`` the score over the spread (standard deviation, plus
    :data:`SPREAD_FLOOR`) of its :func:`background_scores` and ``N`` the places the
    frame holds for the mode's box (the frame's area over the box's, at least 1), the
    contrast is ``sqrt(max(z**2 - 2 ln N, 0))``: where the background's scores are
    Gaussian, ``exp(-contrast**2 / 2)`` is about the number of places in the frame that
    score as high by chance, so one threshold reads the same for small and large objects
    in small and large frames.
    """
    spread = float(np.std(background_scores(hypothesis, model, maps, shape, **score_options)))
    z = float(hypothesis.score) / (spread + SPREAD_FLOOR)
    _, _, bw, bh = hypothesis.box
    places = max(1.0, shape[0] * shape[1] / max(bw * bh, 1.0))
    return math.sqrt(max(z * z - 2.0 * math.log(places), 0.0))
