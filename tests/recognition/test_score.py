"""Instance recognition: the fraction of test features a model explains, and the margin."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from posevote.features.edges import EdgeFeatures
from posevote.geometry import rotate_points
from posevote.model.kernels import orientation_kernel, position_kernel
from posevote.recognition.score import (
    explained_fraction,
    median_spacing,
    median_spacing_reference,
    recognition_margin,
)
from posevote.scoring.score import viewpoint_features


def _reference(test, model, hyp, *, sigma, kappa, kappa_v):
    """Point-by-point transcription of the documented sum, for comparison."""
    x, y, w, h = hyp.box
    gx, gy = 0.1 * w, 0.1 * h
    feats = viewpoint_features(model, hyp.azimuth, hyp.elevation, viewpoint_kappa=kappa_v)
    xy = hyp.scale * rotate_points(feats.xy, hyp.inplane) + np.asarray(hyp.position)
    theta = np.mod(feats.theta + hyp.inplane, np.pi)
    strength = feats.weight / feats.weight.max()
    d = np.sqrt(((xy[:, None, :] - xy[None, :, :]) ** 2).sum(-1))
    np.fill_diagonal(d, np.inf)
    gain = np.median(d.min(axis=1)) / (np.sqrt(2 * np.pi) * sigma)
    values = []
    for p, t in zip(test.xy, test.theta, strict=True):
        if not (x - gx <= p[0] <= x + w + gx and y - gy <= p[1] <= y + h + gy):
            continue
        d2 = ((xy - p) ** 2).sum(-1)
        near = d2 <= (3 * sigma) ** 2
        total = np.sum(strength[near] * position_kernel(d2[near], sigma)
                       * orientation_kernel(theta[near] - t, kappa))
        values.append(min(gain * total, 1.0))
    return float(np.mean(values)) if values else 0.0


@pytest.fixture(scope="module")
def scene(fitted_estimator, draw):
    image = draw(np.radians(40.0), size=128)
    result = fitted_estimator.estimate(image)
    from posevote.features.edges import extract_edges

    features = extract_edges(image, fitted_estimator.edges, training=False)
    return fitted_estimator, result.best, features


def test_matches_pointwise_sum(scene):
    est, hyp, features = scene
    got = explained_fraction(features, est.model_, hyp, position_sigma=3.0, orientation_kappa=8.0,
                             viewpoint_kappa=est.viewpoint_kappa_)
    want = _reference(features, est.model_, hyp, sigma=3.0, kappa=8.0,
                      kappa_v=est.viewpoint_kappa_)
    assert got == pytest.approx(want, rel=1e-9, abs=1e-12)
    assert 0.3 < got <= 1.0


def test_wrong_place_explains_less(scene):
    est, hyp, features = scene
    kw = {"position_sigma": 3.0, "orientation_kappa": 8.0, "viewpoint_kappa": est.viewpoint_kappa_}
    right = explained_fraction(features, est.model_, hyp, **kw)
    moved = dataclasses.replace(hyp, position=(hyp.position[0] + 25.0, hyp.position[1]))
    assert explained_fraction(features, est.model_, moved, box=hyp.box, **kw) < 0.5 * right


def test_empty_box_scores_zero(scene):
    est, hyp, _ = scene
    empty = EdgeFeatures(xy=np.zeros((0, 2)), theta=np.zeros(0))
    assert explained_fraction(empty, est.model_, hyp, position_sigma=3.0, orientation_kappa=8.0,
                              viewpoint_kappa=est.viewpoint_kappa_) == 0.0


def test_recognition_margin():
    assert recognition_margin(np.array([0.2, 0.5, 0.25])) == (1, pytest.approx(2.0))
    assert recognition_margin(np.array([0.4])) == (0, float("inf"))
    assert recognition_margin(np.array([0.0, 0.3])) == (1, float("inf"))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_spacing_kernel_matches_its_reference(seed):
    xy = np.random.default_rng(seed).uniform(0, 60, (300, 2))
    xy[10], xy[20:30, 0] = xy[11], 17.0  # a point 0 from its twin; ties in the sort by x
    assert median_spacing(xy) == pytest.approx(median_spacing_reference(xy), rel=1e-12)
    assert median_spacing(xy[:1]) == median_spacing_reference(xy[:1]) == 1.0
