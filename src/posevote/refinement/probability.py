"""How probable each mode is: the vote's score profile turned into a posterior.

The probes give, at every probed viewpoint ``v``, the best score ``s_v`` over
in-plane angle, scale and position. Read as a likelihood with a sharpness
``k``, ``p(v) ~ exp(k (s_v / max s - 1))``, normalised over the probed
viewpoints. A mode's probability is the mass of the viewpoints within
:data:`MODE_RADIUS` of it that lie nearer to it than to any other mode: the
chance that the true viewpoint is within that radius of this mode. What is
left over (viewpoints far from every mode) is the chance that none is right.

A flat profile, where every side of the object looks the same (a ring, a
plain can), gives every mode about the share of the circle its radius
covers; two equal peaks (a car's front and back) give each about a half. A
robot can look again when the best mode's probability is low instead of
acting on a coin toss. :data:`MODE_SHARPNESS` is chosen on development
folds (``benchmarks/calibrate_modes.py``, docs/DEFAULTS.md).

That share knows the viewpoints but not whether the object is there at all
(an empty frame, another object, a flip the profile does not show), and it
reads differently in each preset's data. :func:`calibrated` therefore maps
the best mode's share and score to the probability that it is right, with
each preset's ``SearchOptions.calibration`` fitted on development folds that
hold the wrong answers, on the estimates the preset reports (over its
``min_score``) or on every one, whichever calibrates the reported ones better
(``benchmarks/calibrate_probability.py``): the probability of a found
estimate, which may overstate below the threshold. The other modes share what
is left in their proportions.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from posevote.geometry import MODE_RADIUS, viewing_direction
from posevote.inference.probes import ProbeSet
from posevote.results import Hypothesis

#: Sharpness ``k`` of the posterior over viewpoints: chosen by
#: ``benchmarks/calibrate_modes.py`` on the coil-loio records (16 folds), the
#: lowest log-loss of "the best mode is within 30 degrees of the truth"; a
#: Platt scaling on top did not lower it (docs/DEFAULTS.md).
MODE_SHARPNESS = 10.0


def mode_probabilities(directions: ArrayLike, profile: ArrayLike, modes: ArrayLike, *,
                       sharpness: float = MODE_SHARPNESS,
                       radius: float = MODE_RADIUS) -> NDArray[np.float64]:
    """The probability of each mode from the score profile over viewpoints.

    Parameters
    ----------
    directions : (V, 3) array_like
        Unit viewing directions of the probed viewpoints.
    profile : (V,) array_like
        Best score at each viewpoint (non-negative).
    modes : (M, 3) array_like
        Unit viewing directions of the modes.
    sharpness, radius : float, optional
        ``k`` of the posterior; the radius of a mode, radians.

    Returns
    -------
    (M,) ndarray
        Probabilities in [0, 1], summing to at most 1; zeros when the
        profile is all zero.
    """
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    s = np.asarray(profile, dtype=np.float64).ravel()
    m = np.asarray(modes, dtype=np.float64).reshape(-1, 3)
    if len(s) != len(d):
        raise ValueError(f"profile has {len(s)} values for {len(d)} directions")
    top = float(s.max()) if s.size else 0.0
    if m.size == 0 or top <= 0.0:
        return np.zeros(len(m))
    weight = np.exp(sharpness * (s / top - 1.0))
    cos = d @ m.T                                     # (V, M)
    nearest = np.argmax(cos, axis=1)
    inside = cos[np.arange(len(d)), nearest] >= np.cos(radius) - 1e-9  # the rim counts
    mass = np.bincount(nearest[inside], weights=weight[inside], minlength=len(m))
    return mass / weight.sum()


def viewpoint_profile(probes: ProbeSet) -> NDArray[np.float64]:
    """The best score at each probed viewpoint (over in-plane angle and scale)."""
    return probes.score.max(axis=(1, 2)) if probes.score.size else np.zeros(0)


def scored_viewpoints(probes: ProbeSet) -> tuple[tuple[float, float, float], ...]:
    """``(azimuth, elevation, score)`` of every probed viewpoint (``PoseEstimate.viewpoint_scores``)."""
    return tuple((float(a), float(e), float(s)) for a, e, s in
                 zip(probes.azimuth, probes.elevation, viewpoint_profile(probes), strict=True))


#: Shares and scores are clipped to this distance from 0 (and 1) before their logarithms.
_TINY = 1e-6

#: The calibration that leaves the posterior's share as it is.
IDENTITY = (1.0, 0.0, 0.0)


def calibrated(share: ArrayLike, score: ArrayLike,
               calibration: tuple[float, float, float]) -> NDArray[np.float64]:
    """The probability that a best mode is right, ``sigmoid(a logit(share) + b ln(score) + c)``
    (``score``: its detection score, the contrast where measured).

    Parameters
    ----------
    share : array_like
        The best mode's :func:`mode_probabilities` (its share of the posterior).
    score : array_like
        Its score (non-negative).
    calibration : (float, float, float)
        ``(a, b, c)`` (``SearchOptions.calibration``); :data:`IDENTITY` returns ``share``.

    Returns
    -------
    ndarray
        Probabilities in [0, 1], the shape of ``share``.

    Examples
    --------
    >>> float(calibrated(0.5, 0.2, (1.0, 0.0, 0.0)))
    0.5
    >>> round(float(calibrated(0.5, 1.0, (2.0, 0.0, 1.0))), 3)
    0.731
    """
    p = np.asarray(share, dtype=np.float64)
    if tuple(calibration) == IDENTITY:
        return p.copy()
    a, b, c = calibration
    q = np.clip(p, _TINY, 1.0 - _TINY)
    s = np.maximum(np.asarray(score, dtype=np.float64), _TINY)
    z = a * np.log(q / (1.0 - q)) + b * np.log(s) + c
    # Past +-700 the logistic is 0 or 1 to double precision (and exp would overflow).
    return 1.0 / (1.0 + np.exp(-np.clip(z, -700.0, 700.0)))


def with_probabilities(hypotheses: Sequence[Hypothesis], probes: ProbeSet,
                       calibration: tuple[float, float, float] = IDENTITY, *,
                       best_share: float | None = None) -> list[Hypothesis]:
    """The hypotheses (best first) with their probabilities: the best mode's
    :func:`calibrated` share of the probes' posterior (or ``best_share``, where a later step
    chose its viewpoint), the others' shares scaled to what is left (the probabilities sum
    to at most 1)."""
    if not hypotheses:
        return []
    modes = viewing_direction(np.array([h.azimuth for h in hypotheses]),
                              np.array([h.elevation for h in hypotheses]))
    p = mode_probabilities(probes.directions, viewpoint_profile(probes), modes)
    if best_share is not None:
        p[0] = best_share
        p[1:] *= min(1.0, (1.0 - best_share) / max(float(p[1:].sum()), _TINY))
    best = float(calibrated(p[0], hypotheses[0].detection_score, calibration))
    rest = float(p[1:].sum())
    if tuple(calibration) != IDENTITY and rest > 0.0:
        p[1:] *= min(1.0, (1.0 - best) / rest)
    p[0] = best
    return [replace(h, probability=float(q)) for h, q in zip(hypotheses, p, strict=True)]
