import numpy as np
import pytest

from posevote.model.kernels import ORIENTATION_KAPPA
from posevote.model.pruning import (
    PRESETS,
    PruningPreset,
    cluster_features,
    prune_model,
    resolve_preset,
)


def test_clusters_respect_the_variance_bound():
    rng = np.random.default_rng(0)
    pose = rng.normal(size=(600, 3)) * 2.0
    app = rng.normal(size=(600, 4)) * 2.0
    labels = cluster_features(pose, app, max_block=128)
    assert labels.min() == 0 and len(np.unique(labels)) == labels.max() + 1
    assert len(np.unique(labels)) < 600  # something was merged
    for lab in np.unique(labels):
        members = labels == lab
        for coords in (pose[members], app[members]):
            variance = np.mean(np.sum((coords - coords.mean(axis=0)) ** 2, axis=1))
            assert variance <= 1.0 + 1e-9


def test_prune_merges_repeated_instances_and_keeps_weight(synthetic_training):
    from posevote import PoseEstimator

    images, az, boxes = synthetic_training
    # The same object twice, as two instances: their features coincide.
    est = PoseEstimator().fit(images + images, np.concatenate([az, az]),
                              boxes=np.vstack([boxes, boxes]), instances=["a"] * 18 + ["b"] * 18)
    full = est.full_model_
    pruned = prune_model(full, PruningPreset(pose_std_deg=2.0, appearance_std=0.3),
                         position_sigma=est.kernel.position_sigma,
                         orientation_kappa=ORIENTATION_KAPPA)
    assert pruned.n_features <= 0.55 * full.n_features
    assert pruned.weight.sum() == pytest.approx(full.weight.sum())
    assert pruned.view.max() < full.n_views and np.all(pruned.theta >= 0)
    assert np.all(pruned.theta < np.pi)


def test_presets_and_errors():
    assert resolve_preset(None) is None and resolve_preset("none") is None
    assert resolve_preset("moderate") == PRESETS["moderate"]
    assert PRESETS["aggressive"].pose_std_deg > PRESETS["moderate"].pose_std_deg
    with pytest.raises(ValueError, match="unknown pruning preset 'harsh'"):
        resolve_preset("harsh")
    with pytest.raises(ValueError, match="must be positive"):
        resolve_preset(PruningPreset(pose_std_deg=0.0, appearance_std=1.0))
