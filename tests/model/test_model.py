import numpy as np
import pytest

from posevote.features import EdgeFeatures
from posevote.model import (
    build_model,
    feature_weights,
    image_density,
    load_model,
    pose_likelihood,
    save_model,
)
from posevote.model.kernels import kappa_for_width, orientation_cutoff, orientation_kernel


def toy_model(shared_feature=True):
    """Three views; view features at distinct places plus one feature common to all."""
    views = []
    for k in range(3):
        xy = [[10.0 * k - 10, 5.0]]
        theta = [0.3 * k]
        if shared_feature:
            xy.append([0.0, -20.0])
            theta.append(1.0)
        views.append(EdgeFeatures(xy=np.array(xy) + 50, theta=np.array(theta)))
    return build_model(views, poses=np.radians([[0, 0, 0], [120, 0, 0], [240, 0, 0]]),
                       centers=np.full((3, 2), 50.0), scales=np.ones(3),
                       box_sizes=np.full((3, 2), 40.0), instances=[0, 0, 0],
                       instance_names=["toy"], reference_size=40.0)


def test_orientation_kernel_is_undirected_and_peaks_at_one():
    assert orientation_kernel(0.0, 5.0) == pytest.approx(1.0)
    assert orientation_kernel(np.pi, 5.0) == pytest.approx(1.0)
    assert orientation_kernel(np.pi / 2, 5.0) < 1e-4
    k = kappa_for_width(0.2, doubled=True)
    assert orientation_kernel(0.2, k) == pytest.approx(0.5)
    assert orientation_kernel(orientation_cutoff(k, 0.1), k) == pytest.approx(0.1)


def test_weights_penalise_the_shared_feature():
    model = toy_model()
    w = feature_weights(model, position_sigma=2.0, orientation_kappa=8.0, viewpoint_kappa=5.0)
    shared = model.xy[:, 1] == -20.0
    assert np.all((w >= 0) & (w <= 1))
    assert w[shared].max() < w[~shared].min()
    assert w[~shared] == pytest.approx(1.0)
    # 2 of 3 views share it, with pose kernel ~0 between views 120 degrees apart
    assert w[shared] == pytest.approx(1 - 2 / 3, abs=0.01)


def test_weights_dense_and_sorted_paths_agree():
    from posevote.model.weights import _instance_weights

    rng = np.random.default_rng(3)
    m, k = 400, 12
    xy = rng.uniform(-20, 20, (m, 2))
    theta = rng.uniform(0, np.pi, m)
    view = rng.integers(0, k, m)
    az = np.linspace(0, 2 * np.pi, k, endpoint=False)
    directions = np.column_stack([np.sin(az), np.cos(az), np.zeros(k)])
    kw = dict(position_sigma=2.0, orientation_kappa=8.0, viewpoint_kappa=4.0, max_pairs=10**7)
    dense = _instance_weights(xy, theta, view, directions, **kw)
    sorted_ = _instance_weights(xy, theta, view, directions, dense_cells=0, **kw)
    assert dense == pytest.approx(sorted_, abs=1e-12)
    assert dense.min() < 0.9


def test_pose_likelihood_peaks_at_the_true_translation():
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


def test_model_file_round_trip(tmp_path):
    model = toy_model()
    save_model(tmp_path / "m.npz", model, {"position_sigma": 2.0}, extra={"k": 1})
    loaded, params, extra, full, descriptors, objectness, regressor = load_model(tmp_path / "m.npz")
    assert full is None and descriptors is None and objectness is None and regressor is None
    assert params == {"position_sigma": 2.0} and extra == {"k": 1}
    assert np.array_equal(loaded.xy, model.xy) and loaded.instance_names == ("toy",)


def test_model_file_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="model file not found"):
        load_model(tmp_path / "none.npz")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"hello")
    with pytest.raises(ValueError, match="junk.npz: not a posevote model file"):
        load_model(junk)
    save_model(tmp_path / "m.npz", toy_model(), {})
    data = (tmp_path / "m.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="cut.npz: not a posevote model file"):
        load_model(tmp_path / "cut.npz")
    np.savez(tmp_path / "foreign.npz", a=np.zeros(3))
    with pytest.raises(ValueError, match="foreign.npz: not a posevote model file"):
        load_model(tmp_path / "foreign.npz")


def test_newer_format_is_refused(tmp_path, monkeypatch):
    import posevote.model.modelfile as mf

    monkeypatch.setattr(mf, "FORMAT_VERSION", 99)
    mf.save_model(tmp_path / "new.npz", toy_model(), {})
    monkeypatch.setattr(mf, "FORMAT_VERSION", 1)
    with pytest.raises(ValueError, match="format version 99 is newer"):
        mf.load_model(tmp_path / "new.npz")


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


def test_instance_sizes_follow_the_instances(tmp_path, draw):
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


def test_model_file_refuses_bad_instance_sizes(tmp_path, monkeypatch):
    import json

    save_model(tmp_path / "m.npz", toy_model(), {})
    with np.load(tmp_path / "m.npz") as data:
        arrays = dict(data)
    header = json.loads(arrays["header"].tobytes())
    header["instance_size"] = [1.0, -2.0]
    arrays["header"] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ValueError, match="bad.npz: corrupt model file \\(instance_size"):
        load_model(tmp_path / "bad.npz")


def test_model_file_refuses_a_bad_box_regressor(tmp_path):
    save_model(tmp_path / "m.npz", toy_model(), {}, box_regressor=np.zeros((8, 4, 5)))
    assert load_model(tmp_path / "m.npz")[6].shape == (8, 4, 5)
    with np.load(tmp_path / "m.npz") as data:
        arrays = dict(data)
    for bad in (np.zeros((8, 3, 5)), np.full((8, 4, 5), np.nan)):
        arrays["box_regressor"] = bad
        np.savez(tmp_path / "bad.npz", **arrays)
        with pytest.raises(ValueError, match="bad.npz: corrupt model file \\(box_regressor"):
            load_model(tmp_path / "bad.npz")
