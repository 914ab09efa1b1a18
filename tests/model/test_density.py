"""The training density psi, the test density phi and p(w); instance sub-models."""

import numpy as np
import pytest

from posevote.features import EdgeFeatures
from posevote.model import (
    image_density,
    pose_likelihood,
)


def test_pose_likelihood_peaks_at_the_true_translation(toy_model):
    model = toy_model(shared_feature=False)
    sel = model.view == 1
    test = EdgeFeatures(xy=model.xy[sel] + [30.0, 40.0], theta=model.theta[sel])
    kw = dict(azimuth=np.radians(120), elevation=0.0, inplane=0.0, scale=1.0,
              position_sigma=2.0, orientation_kappa=8.0, viewpoint_kappa=20.0)
    at_truth = pose_likelihood(model, test, position=(30.0, 40.0), **kw)
    assert at_truth == pytest.approx(1.0, abs=1e-6)
    assert pose_likelihood(model, test, position=(33.0, 40.0), **kw) < at_truth
    # the test density at the features themselves is 1 each
    assert np.allclose(image_density(test, test.xy, test.theta, position_sigma=2.0,
                                    orientation_kappa=8.0), 1.0)


def test_select_instances_reindexes(synthetic_training):
    from posevote import PoseEstimator

    images, az, boxes = synthetic_training
    est = PoseEstimator().fit(images, az, boxes=boxes, instances=["a"] * 6 + ["b"] * 6 + ["c"] * 6)
    full = est.full_model_
    sub = full.select_instances([2, 0])
    assert sub.instance_names == ("c", "a") and sub.n_views == 12
    assert set(sub.view_instance.tolist()) == {0, 1}
    assert sub.n_features == np.sum(np.isin(full.view_instance[full.view], [0, 2]))
    one = full.instance_model(1)
    assert one.instance_names == ("b",) and one.n_views == 6 and one.view.max() == 5
    with pytest.raises(ValueError, match="instance 7 has no training views"):
        full.select_instances([7])


def test_instance_sizes_follow_the_instances(toy_model, tmp_path, draw):
    from posevote import PoseEstimator
    from posevote.data import object_box

    az = np.radians(np.arange(0, 360, 40))
    images = [draw(a) for a in az] + [draw(a, scale=0.8) for a in az]
    boxes = np.array([object_box(im) for im in images])
    est = PoseEstimator().fit(images, np.concatenate([az, az]), boxes=boxes,
                              instances=["big"] * 9 + ["small"] * 9)
    full = est.full_model_
    big, small = full.instance_size
    assert small / big == pytest.approx(0.8, abs=0.05)
    assert (big + small) / 2 == pytest.approx(1.0)  # the reference: the median of two heights
    assert full.instance_model(1).instance_size == (small,)
    assert full.instance_model(1).size_of(0) == small
    assert toy_model().size_of(0) == 1.0  # built without sizes
    est.save(tmp_path / "m.npz")
    assert PoseEstimator.load(tmp_path / "m.npz").full_model_.instance_size == (big, small)


def test_features_of_views_as_a_mask_would_select(toy_model):
    from dataclasses import replace

    toy_model = toy_model()
    views = np.array([0, 2])
    want = np.flatnonzero(np.isin(toy_model.view, views))
    assert len(want) > 0
    np.testing.assert_array_equal(toy_model.features_of(views), want)
    assert len(toy_model.features_of(np.array([], dtype=np.intp))) == 0
    # Features not stored view by view take the mask's way: the same answer.
    order = np.random.default_rng(0).permutation(toy_model.n_features)
    shuffled = replace(toy_model, xy=toy_model.xy[order], theta=toy_model.theta[order],
                       view=toy_model.view[order], weight=toy_model.weight[order])
    np.testing.assert_array_equal(shuffled.features_of(views),
                                  np.flatnonzero(np.isin(shuffled.view, views)))


def test_cached_radius_and_viewpoints_are_what_they_summarise(toy_model):
    from dataclasses import replace

    toy_model = toy_model()
    assert toy_model.rms_radius == pytest.approx(np.sqrt(np.mean(np.sum(toy_model.xy**2, 1))))
    # Two views at one viewpoint count once; the viewpoints come sorted and read-only.
    az, el = toy_model.view_azimuth[::-1].copy(), np.zeros(toy_model.n_views)
    az[1] = az[0]
    pairs = replace(toy_model, view_azimuth=az, view_elevation=el).viewpoints
    assert toy_model.n_views >= 3 and len(pairs) == len(np.unique(az))
    np.testing.assert_array_equal(pairs[:, 0], np.unique(np.round(az, 9)))
    with pytest.raises(ValueError):
        pairs[0, 0] = 1.0


def test_near_views_and_their_average(toy_model):
    from posevote.model.density import near_views, view_average

    model = toy_model()
    values = np.arange(model.n_views * 2, dtype=float).reshape(-1, 2)
    az, el = float(model.view_azimuth[1]), float(model.view_elevation[1])
    # A sharp kernel: only the view itself, whose own row comes back.
    views, k1 = near_views(model, az, el, kappa=1e4, k1_cutoff=0.1)
    assert views.tolist() == [1] and k1.shape == (model.n_views,)
    np.testing.assert_array_equal(view_average(model, values, az, el, kappa=1e4, k1_cutoff=0.1),
                                  values[1])
    # A cutoff no view reaches: the nearest alone.
    assert near_views(model, az, el, kappa=1e4, k1_cutoff=2.0)[0].tolist() == [1]
    # A flat kernel: every view, averaged with its weight.
    views, k1 = near_views(model, az, el, kappa=1e-6, k1_cutoff=0.1)
    assert len(views) == model.n_views
    np.testing.assert_allclose(view_average(model, values, az, el, kappa=1e-6, k1_cutoff=0.1),
                               np.average(values, axis=0, weights=k1))
