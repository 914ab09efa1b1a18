"""Pose-specific feature weights (Eq. 4)."""

import numpy as np
import pytest

from posevote.model import (
    feature_weights,
)


def test_weights_penalise_the_shared_feature(toy_model):
    model = toy_model()
    w = feature_weights(model, position_sigma=2.0, orientation_kappa=8.0, viewpoint_kappa=5.0)
    shared = model.xy[:, 1] == -20.0
    assert np.all((w >= 0) & (w <= 1))
    assert w[shared].max() < w[~shared].min()
    assert w[~shared] == pytest.approx(1.0)
    # 2 of 3 views share it, with pose kernel ~0 between views 120 degrees apart
    assert w[shared] == pytest.approx(1 - 2 / 3, abs=0.01)


@pytest.mark.parametrize("layout", ["square", "row", "duplicates", "far apart"])
def test_weights_agree_with_the_reference(layout):
    from posevote.model.weights import _instance_weights, instance_weights_reference

    rng = np.random.default_rng(3)
    m, k = 400, 12
    # The dense path visits pairs on a grid of cells: a square of many
    # cells, a single row of them, features sharing a place, and clusters
    # so far apart that the cells are made wider than the kernel's reach.
    clusters = np.repeat(rng.choice([-5e4, 5e4], (4, 2)), m // 4, axis=0)
    xy = {"square": rng.uniform(-20, 20, (m, 2)),
          "row": np.column_stack([rng.uniform(-60, 60, m), rng.uniform(0, 1, m)]),
          "duplicates": np.repeat(rng.uniform(-10, 10, (m // 4, 2)), 4, axis=0),
          "far apart": clusters + rng.uniform(-10, 10, (m, 2))}[layout]
    theta = rng.uniform(0, np.pi, m)
    view = rng.integers(0, k, m)
    az = np.linspace(0, 2 * np.pi, k, endpoint=False)
    directions = np.column_stack([np.sin(az), np.cos(az), np.zeros(k)])
    kw = dict(position_sigma=2.0, orientation_kappa=8.0, viewpoint_kappa=4.0)
    reference = instance_weights_reference(xy, theta, view, directions, **kw)
    whole = _instance_weights(xy, theta, view, directions, **kw)
    assert whole == pytest.approx(reference, abs=1e-12)
    assert whole.min() < 0.9
