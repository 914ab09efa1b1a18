import numpy as np
import pytest

from posevote import PoseEstimator
from posevote.geometry import rotate_points
from posevote.keypoints.model import KeypointCollector, detect_keypoints


def test_detect_keypoints_keeps_to_the_mask(cylinder):
    image, box = cylinder(0.0)
    xy, desc = detect_keypoints(image)
    assert len(xy) > 30 and desc.dtype == np.uint8 and desc.shape == (len(xy), 128)
    mask = np.zeros(image.shape, bool)
    mask[:, :64] = True
    left, _ = detect_keypoints(image, mask)
    assert 0 < len(left) < len(xy) and np.all(left[:, 0] < 64.5)
    none, empty = detect_keypoints(np.zeros((64, 64)))
    assert none.shape == (0, 2) and empty.shape == (0, 128)


def test_collector_keeps_keypoints_upright_from_the_box_centre(cylinder):
    image, box = cylinder(0.3)
    collector = KeypointCollector(np.array([box]))
    xy, desc = detect_keypoints(image)
    upright, same = collector.read(image, box, None, np.array([0.3, 0.0, 0.5]))
    np.testing.assert_array_equal(same, desc)
    centre = box[:2] + (box[2:] - 1) / 2
    np.testing.assert_allclose(rotate_points(upright, 0.5) + centre, xy, atol=1e-9)


def _fit(draw, azimuths, keypoints=True):
    views = [draw(a) for a in azimuths]
    return PoseEstimator.from_preset("default", refine__keypoints=keypoints).fit(
        [v[0] for v in views], np.column_stack([azimuths, np.zeros((len(azimuths), 2))]),
        boxes=[v[1] for v in views])


def test_model_holds_each_views_keypoints_and_the_file_keeps_them(cylinder, tmp_path):
    azimuths = np.radians(np.arange(0, 360, 40))
    est = _fit(cylinder, azimuths)
    model = est.full_model_
    assert model.keypoint_xy is not None
    assert set(np.unique(model.keypoint_view).tolist()) == set(range(len(azimuths)))
    assert model.keypoint_descriptor.shape == (len(model.keypoint_xy), 128)
    # Reference pixels from each box centre: within the cylinder's half-diagonal.
    assert np.abs(model.keypoint_xy).max() < np.hypot(40, 40) + 1
    est.save(tmp_path / "m.npz")
    again = PoseEstimator.load(tmp_path / "m.npz").full_model_
    for name in ("keypoint_xy", "keypoint_descriptor", "keypoint_view"):
        np.testing.assert_array_equal(getattr(again, name), getattr(model, name))
    assert again.keypoint_descriptor.dtype == np.uint8


def test_model_without_the_step_holds_no_keypoints(cylinder):
    est = _fit(cylinder, np.radians([0.0, 90.0]), keypoints=False)
    assert est.full_model_.keypoint_xy is None


def test_partial_fit_adds_the_new_views_keypoints(cylinder):
    azimuths = np.radians(np.arange(0, 360, 40))
    whole = _fit(cylinder, azimuths).full_model_
    est = _fit(cylinder, azimuths[:5])
    views = [cylinder(a) for a in azimuths[5:]]
    est.partial_fit([v[0] for v in views],
                    np.column_stack([azimuths[5:], np.zeros((4, 2))]), boxes=[v[1] for v in views])
    grown = est.full_model_
    np.testing.assert_array_equal(grown.keypoint_view, whole.keypoint_view)
    np.testing.assert_array_equal(grown.keypoint_descriptor, whole.keypoint_descriptor)
    np.testing.assert_allclose(grown.keypoint_xy, whole.keypoint_xy, atol=1e-9)


def test_one_instances_model_keeps_its_own_keypoints(cylinder):
    views = [cylinder(a) for a in (0.0, 1.0, 2.0)]
    est = PoseEstimator.from_preset("default", refine__keypoints=True).fit(
        [v[0] for v in views] * 2, np.column_stack([[0.0, 1.0, 2.0] * 2, np.zeros((6, 2))]),
        boxes=[v[1] for v in views] * 2, instances=["a"] * 3 + ["b"] * 3)
    full = est.full_model_
    b = full.select_instances([1])
    assert b.n_views == 3
    np.testing.assert_array_equal(b.keypoint_view, full.keypoint_view[full.keypoint_view >= 3] - 3)
    np.testing.assert_array_equal(b.keypoint_descriptor,
                                  full.keypoint_descriptor[full.keypoint_view >= 3])


@pytest.mark.parametrize("change", ["view", "shape", "nan"])
def test_corrupt_keypoints_are_refused(cylinder, tmp_path, change):
    est = _fit(cylinder, np.radians([0.0, 120.0, 240.0]))
    est.save(tmp_path / "m.npz")
    with np.load(tmp_path / "m.npz") as f:
        arrays = dict(f)
    if change == "view":
        arrays["keypoint_view"] = arrays["keypoint_view"] + 3
    elif change == "shape":
        arrays["keypoint_descriptor"] = arrays["keypoint_descriptor"][:, :64]
    else:
        arrays["keypoint_xy"] = arrays["keypoint_xy"].astype(float)
        arrays["keypoint_xy"][0, 0] = np.nan
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ValueError, match="bad.npz: corrupt model file"):
        PoseEstimator.load(tmp_path / "bad.npz")
