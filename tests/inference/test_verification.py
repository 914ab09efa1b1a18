"""Appearance verification: descriptors of boxes and the choice among search candidates."""

from __future__ import annotations

import numpy as np
import pytest

from posevote.inference.search import ProbeSet
from posevote.inference.verification import (
    background_boxes,
    box_descriptor,
    descriptor_length,
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


def test_verification_prefers_the_box_that_looks_like_its_view(draw):
    az = np.radians(np.arange(0, 360, 20.0))
    window = (48, 48)
    train = np.array([box_descriptor(draw(a, size=96), (0, 0, 96, 96), window) for a in az])
    scene = np.zeros((200, 300))
    scene[50:146, 20:116] = draw(np.radians(40.0), size=96)   # the object, at 40 degrees
    rng = np.random.default_rng(0)
    scene[50:146, 180:276] = rng.random((96, 96)) > 0.7       # clutter
    # Candidate 0 (highest score) sits on the clutter, candidate 2 (40 degrees) on the object.
    probes = _probes([(228, 98), (228, 98), (68, 98)], [0.9, 0.8, 0.5])
    found = verify_candidates(probes, scene, train, az, np.zeros(len(az)), window=window,
                              n_candidates=3, tolerance=np.radians(10.0))
    assert found is not None and found[0] == (2, 0, 0)
    # Only the best candidate verified: it is returned whatever it looks like.
    found = verify_candidates(probes, scene, train, az, np.zeros(len(az)), window=window,
                              n_candidates=1, tolerance=np.radians(10.0))
    assert found is not None and found[0] == (0, 0, 0)


def test_the_short_list_limits_the_choice(draw):
    az = np.radians(np.arange(0, 360, 20.0))
    window = (48, 48)
    train = np.array([box_descriptor(draw(a, size=96), (0, 0, 96, 96), window) for a in az])
    scene = np.zeros((200, 300))
    scene[50:146, 20:116] = draw(np.radians(40.0), size=96)
    scene[50:146, 180:276] = np.random.default_rng(0).random((96, 96)) > 0.7
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
