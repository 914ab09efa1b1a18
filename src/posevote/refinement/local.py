"""Local continuous maximisation of p(w) in (in-plane angle, scale, translation).

Beyond the paper: after the distribution fit has placed the viewpoint between
the training views, the exact likelihood p(w) (Eq. 3) of that viewpoint is
maximised over ``w2`` and ``w3`` with the narrow appearance kernel, starting
from the fit. The grid search had to widen its kernel to tolerate its own
step size; this step takes the estimate back to the resolution of the
features, which is what puts the object's position within a pixel or two.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.optimize import minimize

from posevote.inference.search import viewpoint_features
from posevote.inference.voting import TestMaps, gather_score
from posevote.model.density import PoseModel
from posevote.refinement.fitting import box_from_pose
from posevote.results import Hypothesis


def polish_pose(hypothesis: Hypothesis, model: PoseModel, maps: TestMaps, *,
                viewpoint_kappa: float, use_weights: bool = True, k1_cutoff: float = 0.1,
                max_shift: float = 8.0) -> Hypothesis:
    """Maximise the exact p(w) around a hypothesis over (alpha, log s, u, v).

    Parameters
    ----------
    hypothesis : Hypothesis
        Starting pose (its viewpoint is kept).
    model : PoseModel
        Training pairs.
    maps : TestMaps
        The test image, tabulated with the narrow kernel.
    viewpoint_kappa, use_weights, k1_cutoff
        As in :func:`posevote.inference.search.viewpoint_features`.
    max_shift : float, optional
        The translation moves at most this many pixels; the angle and scale
        at most by the equivalent at the model's typical radius.

    Returns
    -------
    Hypothesis
        The polished pose, or the input if nothing better was found.
    """
    feats = viewpoint_features(model, hypothesis.azimuth, hypothesis.elevation,
                               viewpoint_kappa=viewpoint_kappa, use_weights=use_weights,
                               k1_cutoff=k1_cutoff)
    if feats.weight.sum() <= 0:
        return hypothesis
    radius = max(float(np.sqrt(np.mean(np.sum(feats.xy**2, axis=1)))) * hypothesis.scale, 1.0)
    # Work in units where one step moves a typical feature by about a pixel.
    unit = np.array([1.0 / radius, 1.0 / radius, 1.0, 1.0])
    start = np.array([hypothesis.inplane, np.log(hypothesis.scale), *hypothesis.position])

    def negative_score(z: np.ndarray) -> float:
        alpha, log_s, u, v = start + z * unit
        if np.any(np.abs(z) > max_shift):
            return 0.0
        return -gather_score(maps.density, feats.xy, feats.theta, feats.weight, alpha,
                             float(np.exp(log_s)), u, v)

    initial = -negative_score(np.zeros(4))
    result = minimize(negative_score, np.zeros(4), method="Nelder-Mead",
                      options={"xatol": 0.05, "fatol": 1e-5, "maxfev": 400,
                               "initial_simplex": np.vstack([np.zeros(4), 1.5 * np.eye(4)])})
    if not np.isfinite(result.fun) or -result.fun <= initial:
        return hypothesis
    alpha, log_s, u, v = start + result.x * unit
    scale = float(np.exp(log_s))
    return replace(hypothesis, inplane=float(alpha), scale=scale, position=(float(u), float(v)),
                   box=box_from_pose(np.array([u, v]), feats.box * scale, float(alpha)))
