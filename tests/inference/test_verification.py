"""Appearance verification: descriptors of boxes and the choice among search candidates."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from posevote.geometry import box_iou
from posevote.inference.search import ProbeSet
from posevote.inference.verification import (
    background_boxes,
    box_descriptor,
    box_grid,
    box_offsets,
    descriptor_length,
    jittered_boxes,
    jittered_nearest_view,
    medoid_view,
    nearest_view,
    regress_box,
    regress_described,
    shift_box,
    train_box_regression,
    train_objectness,
    verify_candidates,
    window_shape,
)


def test_window_follows_the_boxes_shape():
    assert window_shape(np.array([[200.0, 100.0], [180.0, 100.0], [220.0, 100.0]])) == (48, 96)
    assert window_shape(np.array([[10.0, 100.0]])) == (48, 24)
    assert window_shape(np.array([[1000.0, 10.0]])) == (48, 144)


def test_descriptor_of_a_crop_is_where_it_lies(draw):
    obj = draw(np.radians(30.0), size=96)
    big = np.zeros((200, 300))
    big[50:146, 120:216] = obj
    window = (48, 48)
    a = box_descriptor(obj, (0, 0, 96, 96), window)
    b = box_descriptor(big, (120, 50, 96, 96), window)
    assert a is not None and a.shape == (descriptor_length(window),)
    np.testing.assert_allclose(a, b, atol=1e-6)
    assert box_descriptor(big, (295, 10, 40, 40), window) is None
    assert box_descriptor(big, (-100, -100, 50, 50), window) is None


def _probes(centres, scores, size=96.0):
    v = len(scores)
    return ProbeSet(azimuth=np.radians(np.arange(v) * 20.0), elevation=np.zeros(v),
                    inplane=np.zeros(1), scale=np.ones(1),
                    score=np.asarray(scores, float).reshape(v, 1, 1),
                    translation=np.asarray(centres, float).reshape(v, 1, 1, 2),
                    box=np.full((v, 2), size))


def _views_and_scene(draw):
    """Training descriptors every 20 degrees, and a scene: the object at 40 degrees
    in (20, 50, 96, 96), clutter in (180, 50, 96, 96)."""
    az = np.radians(np.arange(0, 360, 20.0))
    window = (48, 48)
    train = np.array([box_descriptor(draw(a, size=96), (0, 0, 96, 96), window) for a in az])
    scene = np.zeros((200, 300))
    scene[50:146, 20:116] = draw(np.radians(40.0), size=96)
    scene[50:146, 180:276] = np.random.default_rng(0).random((96, 96)) > 0.7
    return az, window, train, scene


def test_verification_prefers_the_box_that_looks_like_its_view(draw):
    az, window, train, scene = _views_and_scene(draw)
    # Candidate 0 (highest score) sits on the clutter, candidate 2 (40 degrees) on the object.
    probes = _probes([(228, 98), (228, 98), (68, 98)], [0.9, 0.8, 0.5])
    found = verify_candidates(probes, scene, train, az, np.zeros(len(az)), window=window,
                              n_candidates=3, tolerance=np.radians(10.0))
    assert found is not None and found[0] == (2, 0, 0)
    # Only the best candidate verified: it is returned whatever it looks like.
    found = verify_candidates(probes, scene, train, az, np.zeros(len(az)), window=window,
                              n_candidates=1, tolerance=np.radians(10.0))
    assert found is not None and found[0] == (0, 0, 0)


def test_candidates_are_judged_on_their_regressed_boxes(draw):
    az, window, train, scene = _views_and_scene(draw)
    # Candidate 2 (40 degrees) is 30 pixels to the right of the object; a
    # regression that moves every box 10 pixels left per step (three steps)
    # puts it exactly on the object, whose descriptor is the training view's.
    probes = _probes([(228, 98), (228, 98), (98, 98)], [0.9, 0.8, 0.5])
    left = np.zeros((1, 4, descriptor_length(window) + 1))
    left[0, 0, -1] = -10.0 / 96.0
    kw = {"window": window, "n_candidates": 3, "tolerance": np.radians(10.0)}
    moved = verify_candidates(probes, scene, train, az, np.zeros(len(az)), regressor=left, **kw)
    assert moved is not None and moved[0] == (2, 0, 0) and moved[1] < 1e-3
    plain = verify_candidates(probes, scene, train, az, np.zeros(len(az)), **kw)
    assert plain is not None and plain[1] > 0.5


def test_the_short_list_limits_the_choice(draw):
    az, window, train, scene = _views_and_scene(draw)
    probes = _probes([(228, 98), (228, 98), (68, 98)], [0.9, 0.8, 0.5])
    clutter = box_descriptor(scene, (180, 50, 96, 96), window)
    # A classifier that finds the clutter most object-like: with a short
    # list of one, the clutter wins; with all three, the object does.
    likes_clutter = np.r_[clutter, 0.0].astype(np.float64)
    kw = {"window": window, "n_candidates": 3, "tolerance": np.radians(10.0),
          "objectness": likes_clutter}
    assert verify_candidates(probes, scene, train, az, np.zeros(len(az)), shortlist=1,
                             **kw)[0] == (0, 0, 0)
    assert verify_candidates(probes, scene, train, az, np.zeros(len(az)), shortlist=3,
                             **kw)[0] == (2, 0, 0)


def test_the_objectness_weight_trades_distance_for_object_likeness(draw):
    az, window, train, scene = _views_and_scene(draw)
    probes = _probes([(228, 98), (228, 98), (68, 98)], [0.9, 0.8, 0.5])
    clutter = box_descriptor(scene, (180, 50, 96, 96), window)
    obj = box_descriptor(scene, (20, 50, 96, 96), window)
    likes_clutter = np.r_[clutter, 0.0].astype(np.float64)
    kw = {"window": window, "n_candidates": 3, "tolerance": np.radians(10.0),
          "objectness": likes_clutter, "shortlist": 3}
    # The object's box is a training view (distance 0); the clutter's is far
    # but the classifier likes it: a weight beyond the distance gap over the
    # score gap lets the clutter win, none or a small one keeps the object.
    clutter_dist = verify_candidates(probes, scene, train, az, np.zeros(len(az)),
                                     n_candidates=1, window=window,
                                     tolerance=np.radians(10.0))[1]
    gap = float(clutter @ clutter - obj @ clutter)
    assert gap > 0
    turn = clutter_dist / gap
    for weight, winner in ((0.0, (2, 0, 0)), (0.5 * turn, (2, 0, 0)), (2.0 * turn, (0, 0, 0))):
        found = verify_candidates(probes, scene, train, az, np.zeros(len(az)),
                                  objectness_weight=weight, **kw)
        assert found is not None and found[0] == winner


def test_background_boxes_miss_the_object_and_repeat_with_the_seed():
    box = (100.0, 60.0, 120.0, 60.0)
    a = background_boxes((250, 376), box, np.random.default_rng(3), attempts=50)
    b = background_boxes((250, 376), box, np.random.default_rng(3), attempts=50)
    assert a == b and len(a) > 10
    for x, y, w, h in a:
        iw = max(0.0, min(x + w, 220.0) - max(x, 100.0))
        ih = max(0.0, min(y + h, 120.0) - max(y, 60.0))
        assert iw * ih / (w * h + 120.0 * 60.0 - iw * ih) < 0.4


def test_objectness_separates_object_from_background():
    rng = np.random.default_rng(0)
    pos = rng.normal(1.0, 0.3, (30, 8)).astype(np.float32)
    neg = rng.normal(-1.0, 0.3, (60, 8)).astype(np.float32)
    w = train_objectness(pos, neg)
    assert w is not None and w.shape == (9,)
    assert np.all(pos @ w[:-1] + w[-1] > 0) and np.all(neg @ w[:-1] + w[-1] < 0)
    assert train_objectness(pos, neg[:5]) is None


def test_no_candidate_inside_the_image_gives_none(draw):
    window = (48, 48)
    train = np.array([box_descriptor(draw(0.0, size=96), (0, 0, 96, 96), window)])
    probes = _probes([(-500, -500)], [1.0])
    assert verify_candidates(probes, np.zeros((100, 100)), train, np.zeros(1), np.zeros(1),
                             window=window, n_candidates=5, tolerance=0.2) is None


def test_estimator_verification_round_trip(fitted_estimator, draw, tmp_path):
    from posevote import PoseEstimator

    est = PoseEstimator(**{**fitted_estimator.get_params(), "verify_candidates": 10})
    est.set_params(scale_range=(0.9, 1.1))
    est.fit([draw(a) for a in np.radians(np.arange(0, 360, 20.0))],
            np.radians(np.arange(0, 360, 20.0)))
    assert est.view_descriptors_.shape[0] == 18
    image = draw(np.radians(60.0))
    result = est.estimate(image)
    assert result.found
    assert abs(np.degrees(result.best.azimuth) - 60.0) < 10.0
    est.save(tmp_path / "m.npz")
    loaded = PoseEstimator.load(tmp_path / "m.npz")
    np.testing.assert_array_equal(loaded.view_descriptors_, est.view_descriptors_)
    if est.objectness_ is None:
        assert loaded.objectness_ is None
    else:
        np.testing.assert_array_equal(loaded.objectness_, est.objectness_)
    assert loaded.estimate(image).best == result.best
    del loaded.view_descriptors_
    with pytest.raises(ValueError, match="retrain"):
        loaded.estimate(image)


_BOX = st.tuples(st.floats(-50, 200), st.floats(-50, 200), st.floats(5, 300), st.floats(5, 300))


@given(_BOX, _BOX)
def test_box_offsets_lead_to_the_target(box, target):
    np.testing.assert_allclose(shift_box(box, box_offsets(box, target)), target, atol=1e-6)
    np.testing.assert_allclose(box_offsets(target, target), 0.0, atol=1e-12)


def test_jittered_boxes_stay_near_and_repeat():
    box = (40.0, 30.0, 100.0, 50.0)
    a = jittered_boxes(box, np.random.default_rng(3), n=50)
    b = jittered_boxes(box, np.random.default_rng(3), n=50)
    assert a == b and len(a) == 50
    d = np.array([box_offsets(box, j) for j in a])
    assert np.all(np.abs(d[:, :2]) <= 0.15 * np.exp(0.15) + 1e-9)
    assert np.all(np.abs(d[:, 2:]) <= 0.15 * 1.5 + 1e-9)
    assert np.ptp(d, axis=0).min() > 0.05


def _scene(draw, azimuth, centre=(110.0, 90.0)):
    """The synthetic object at ``azimuth`` on a 200 x 220 canvas, and its box."""
    from posevote.data import object_box

    img = np.zeros((200, 220))
    obj = draw(azimuth, size=96)
    x0, y0 = int(centre[0] - 48), int(centre[1] - 48)
    img[y0:y0 + 96, x0:x0 + 96] = obj
    x, y, w, h = object_box(obj)
    return img, (x + x0, y + y0, w, h)


def test_box_regression_moves_a_misplaced_box_onto_the_object(draw):
    rng = np.random.default_rng(0)
    window = (48, 48)
    az = np.radians(np.arange(0.0, 360.0, 5.0))
    descriptors, offsets, azimuths = [], [], []
    for a in az:
        img, box = _scene(draw, a)
        for b in jittered_boxes(box, rng, n=12):
            descriptors.append(box_descriptor(img, b, window))
            offsets.append(box_offsets(b, box))
            azimuths.append(a)
    regressor = train_box_regression(np.array(descriptors), np.array(offsets), np.array(azimuths),
                                     bins=4, alpha=10.0)
    assert regressor.shape == (4, 4, descriptor_length(window) + 1)
    before, after = [], []
    for a in np.radians([25.0, 95.0, 205.0, 310.0]):
        img, truth = _scene(draw, a, centre=(100.0, 100.0))
        x, y, w, h = truth
        off = (x + 0.15 * w, y - 0.12 * h, 0.85 * w, 1.12 * h)
        before.append(box_iou(off, truth))
        after.append(box_iou(regress_box(img, off, regressor, a, window=window), truth))
    # Every box ends nearer the object (IoU 0.77 before; 0.82-0.96 after over seeds 0-3).
    assert np.mean(after) > np.mean(before) + 0.08 and min(after) > max(before)
    # A box outside the image has no descriptor and stays where it is.
    far = (500.0, 500.0, 30.0, 30.0)
    assert regress_box(np.zeros((50, 50)), far, regressor, 0.0, window=window) == far
    # From a known descriptor: the same box, and the moved box's descriptor with it.
    moved, d = regress_described(img, off, box_descriptor(img, off, window), regressor, a,
                                 window=window)
    assert moved == regress_box(img, off, regressor, a, window=window)
    np.testing.assert_array_equal(d, box_descriptor(img, moved, window))
    assert regress_described(img, off, None, regressor, a, window=window) == (off, None)


def test_nearest_view_within_the_window():
    descriptors = np.eye(4, dtype=np.float32)
    directions = np.array([[np.cos(t), np.sin(t), 0.0] for t in np.radians([0, 30, 90, 180])])
    probe = np.array([0.1, 0.2, 0.0, 0.9], dtype=np.float32)   # most like view 3 (180 degrees)
    assert nearest_view(probe, descriptors, directions, directions[0],
                        window=np.pi) == 3
    assert nearest_view(probe, descriptors, directions, directions[0],
                        window=np.radians(45.0)) == 1
    assert nearest_view(probe, descriptors, directions[:1], directions[3],
                        window=np.radians(45.0)) is None


def test_box_grid_shifts_and_scales_about_the_centre():
    box = (40.0, 30.0, 100.0, 50.0)
    grid = box_grid(box, 0.1)
    assert grid.shape == (27, 4)
    np.testing.assert_allclose(grid[13], box)
    d = np.array([box_offsets(box, b) for b in grid])
    np.testing.assert_allclose(np.unique(np.round(d[:, 0], 9)), [-0.1, 0.0, 0.1])
    np.testing.assert_allclose(np.unique(np.round(d[:, 1], 9)), [-0.1, 0.0, 0.1])
    np.testing.assert_allclose(np.unique(np.round(np.exp(d[:, 2]), 9)), [0.9, 1.0, 1.1])
    np.testing.assert_allclose(d[:, 2], d[:, 3])   # the aspect is kept
    np.testing.assert_allclose(box_grid(box, 0.0), np.tile(box, (27, 1)))


def test_medoid_view_is_the_central_one():
    directions = np.array([[np.cos(t), np.sin(t), 0.0] for t in np.radians([0, 10, 20, 170])])
    assert medoid_view([0, 1, 2], directions) == 1
    # An outlier does not drag it: the medoid is one of the views given.
    assert medoid_view([3, 0, 1, 1, 2], directions) == 1
    assert medoid_view([2], directions) == 2
    assert medoid_view([0, 2], directions) == 0   # a tie goes to the first


def test_jittered_nearest_view_agrees_with_the_single_box_on_a_clean_view(draw):
    window = (48, 48)
    az = np.radians(np.arange(0.0, 360.0, 30.0))
    scenes = [_scene(draw, a) for a in az]
    descriptors = np.array([box_descriptor(img, box, window) for img, box in scenes])
    directions = np.array([[np.cos(a), np.sin(a), 0.0] for a in az])
    img, box = _scene(draw, np.radians(62.0))
    k = jittered_nearest_view(img, box, descriptors, directions, directions[2],
                              window=np.radians(45.0), descriptor_window=window, fraction=0.05)
    assert k == 2
    single = nearest_view(box_descriptor(img, box, window), descriptors, directions,
                          directions[2], window=np.radians(45.0))
    assert single == k
    # No view within the window, or no box that can be described: None.
    assert jittered_nearest_view(img, box, descriptors[:1], directions[:1], directions[6],
                                 window=np.radians(45.0), descriptor_window=window,
                                 fraction=0.05) is None
    assert jittered_nearest_view(img, (500.0, 500.0, 20.0, 20.0), descriptors, directions,
                                 directions[2], window=np.radians(45.0),
                                 descriptor_window=window, fraction=0.05) is None
