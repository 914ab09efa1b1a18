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
folds so that the probabilities are calibrated (``benchmarks/calibrate_modes.py``,
docs/DEFAULTS.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from posevote.geometry import viewing_direction
from posevote.inference.probes import ProbeSet
from posevote.results import Hypothesis

#: A mode is right when the true viewpoint is within this angle of it.
MODE_RADIUS = np.radians(30.0)

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


def with_probabilities(hypotheses: Sequence[Hypothesis], probes: ProbeSet) -> list[Hypothesis]:
    """The hypotheses with their :func:`mode_probabilities` from the probes' profile."""
    if not hypotheses:
        return []
    modes = viewing_direction(np.array([h.azimuth for h in hypotheses]),
                              np.array([h.elevation for h in hypotheses]))
    p = mode_probabilities(probes.directions, viewpoint_profile(probes), modes)
    return [replace(h, probability=float(q)) for h, q in zip(hypotheses, p, strict=True)]
