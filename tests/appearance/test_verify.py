"""Appearance verification: the choice among search candidates, and the nearest view."""

from __future__ import annotations

import numpy as np

from posevote.appearance.descriptors import box_descriptor
from posevote.appearance.model import box_offsets
from posevote.appearance.verify import (
    box_grid,
    jittered_nearest_view,
    medoid_view,
    nearest_view,
    verify_candidates,
)
from posevote.features.hog import descriptor_length
from posevote.inference.probes import ProbeSet


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


def test_the_objectness_weight_trades_distance_for_object_likeness(draw):
    az, window, train, scene = _views_and_scene(draw)
    probes = _probes([(228, 98), (228, 98), (68, 98)], [0.9, 0.8, 0.5])
    clutter = box_descriptor(scene, (180, 50, 96, 96), window)
    obj = box_descriptor(scene, (20, 50, 96, 96), window)
    likes_clutter = np.r_[clutter, 0.0].astype(np.float64)
    kw = {"window": window, "n_candidates": 3, "tolerance": np.radians(10.0),
          "objectness": likes_clutter}
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


def test_no_candidate_inside_the_image_gives_none(draw):
    window = (48, 48)
    train = np.array([box_descriptor(draw(0.0, size=96), (0, 0, 96, 96), window)])
    probes = _probes([(-500, -500)], [1.0])
    assert verify_candidates(probes, np.zeros((100, 100)), train, np.zeros(1), np.zeros(1),
                             window=window, n_candidates=5, tolerance=0.2) is None


def test_verify_searches_again_inside_the_winners_box(draw, tmp_path):
    from posevote import PoseEstimator
    from posevote.appearance import AppearanceOptions
    from posevote.appearance.verify import verify
    from posevote.features.edges import extract_edges
    from posevote.inference.setup import search_maps

    az = np.radians(np.arange(0, 360, 20.0))
    est = PoseEstimator(appearance=AppearanceOptions(candidates=10))
    est.fit([draw(a) for a in az], az)
    assert est.appearance_model_.descriptors.shape[0] == 18
    scene = np.zeros((200, 300))
    scene[36:164, 20:148] = draw(np.radians(60.0))
    scene[36:164, 160:288] = np.random.default_rng(0).random((128, 128)) > 0.7
    img = scene
    feats = extract_edges(img, est.edges, training=False)
    setup = est.setup()
    maps = search_maps(feats, img.shape, est.model_, setup)
    probes = est.probe(scene)[0]
    located = verify(probes, img, feats, maps, est.model_, est.appearance_model_,
                     est.appearance, setup)
    assert located is not None
    inside, _, again, box = located
    assert 0 < len(inside) < len(feats) and 10 < box[0] + box[2] / 2 < 160
    assert again.score.shape[0] <= probes.score.shape[0]
    result = est.estimate(scene)
    assert result.found and abs(np.degrees(result.best.azimuth) - 60.0) < 15.0
    est.save(tmp_path / "m.npz")
    loaded = PoseEstimator.load(tmp_path / "m.npz")
    np.testing.assert_array_equal(loaded.appearance_model_.descriptors,
                                  est.appearance_model_.descriptors)
    assert loaded.estimate(scene).best == result.best


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


def test_jittered_nearest_view_agrees_with_the_single_box_on_a_clean_view(draw, placed):
    window = (48, 48)
    az = np.radians(np.arange(0.0, 360.0, 30.0))
    scenes = [placed(a) for a in az]
    descriptors = np.array([box_descriptor(img, box, window) for img, box in scenes])
    directions = np.array([[np.cos(a), np.sin(a), 0.0] for a in az])
    img, box = placed(np.radians(62.0))
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

