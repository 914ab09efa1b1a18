from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial import cKDTree

from posevote import PoseEstimator
from posevote.data import object_box
from posevote.features import EdgeFeatures
from posevote.features.edges import extract_edges, normalize_features
from posevote.model.morph import (
    ViewCrops,
    morphed_positions,
    view_neighbours,
    view_shifts,
)
from posevote.scoring.score import viewpoint_features


def test_view_neighbours_pairs_views_of_one_instance():
    az = np.radians([0.0, 40.0, 20.0, 340.0, 0.0, 180.0, 100.0])
    el = np.zeros(7)
    inst = np.array([0, 0, 0, 0, 1, 1, 2])
    nb = view_neighbours(az, el, inst)
    # Instance 0 is a closed turntable 340, 0, 20, 40 with a gap 40 -> 340 too wide.
    assert nb[:4].tolist() == [[2, 3], [-1, 2], [1, 0], [0, -1]]
    # Half a turn apart is too far to morph; a lone view has no neighbour.
    assert nb[4:].tolist() == [[-1, -1], [-1, -1], [-1, -1]]


def test_views_over_the_sphere_pair_along_their_ring_and_their_column():
    # Three rings of four azimuths: columns 0/1 along the ring (closed), 2/3 along the
    # column of equal azimuth (open at the lowest and highest elevations).
    az = np.radians(np.tile([0.0, 30.0, 60.0, 90.0], 3))
    el = np.radians(np.repeat([0.0, 20.0, 40.0], 4))
    nb = view_neighbours(az, el, np.zeros(12, int))
    assert nb.shape == (12, 4)
    assert nb[5].tolist() == [6, 4, 9, 1]
    # 90 -> 0 is a 270-degree gap: too far; the top ring has no view above.
    assert nb[11].tolist() == [-1, 10, -1, 7]
    assert nb[0].tolist() == [1, -1, 4, -1]


def test_scattered_views_have_no_neighbours():
    nb = view_neighbours(np.radians([0.0, 20.0]), np.radians([0.0, 10.0]), np.zeros(2, int))
    assert (nb == -1).all()


def _rectangle(width: int) -> np.ndarray:
    img = np.zeros((96, 128))
    img[30:66, 64 - width // 2:64 + width // 2] = 0.8
    return img


def test_shifts_follow_a_widening_rectangle():
    # The rectangle widens by 12 px about a fixed centre: its left side moves
    # 6 px left and its right side 6 px right from the first view to the second.
    images = [_rectangle(40), _rectangle(52)]
    boxes = np.array([object_box(im) for im in images])
    crops = ViewCrops()
    for im, box in zip(images, boxes, strict=True):
        crops.add(im, box)
    side_x = np.array([44.0, 83.0])
    feats = [EdgeFeatures(xy=np.array([[x, 48.0] for x in side_x]), theta=np.full(2, np.pi / 2)),
             EdgeFeatures(xy=np.array([[38.0, 48.0], [89.0, 48.0]]), theta=np.full(2, np.pi / 2))]
    centres = boxes[:, :2] + (boxes[:, 2:] - 1) / 2
    shift = view_shifts(feats, crops, np.array([[1, -1], [-1, 0]]), centers=centres,
                        scales=np.ones(2), inplanes=np.zeros(2))
    assert shift.shape == (4, 2, 2)
    assert shift[0, 0, 0] == pytest.approx(-6.0, abs=1.5)
    assert shift[1, 0, 0] == pytest.approx(6.0, abs=1.5)
    assert shift[2, 1, 0] == pytest.approx(6.0, abs=1.5)
    assert np.all(shift[:2, 1] == 0) and np.all(shift[2:, 0] == 0)


def test_morphed_positions_move_in_proportion_to_the_azimuth():
    xy = np.zeros((2, 2))
    shift = np.zeros((2, 2, 2))
    shift[:, 0] = [4.0, 0.0]     # toward the next view
    shift[:, 1] = [0.0, -2.0]    # toward the previous view
    view_az = np.radians([0.0, 20.0, 340.0])
    nb = np.array([[1, 2], [-1, 0], [0, -1]])
    view = np.array([0, 0])
    assert morphed_positions(xy, shift, view, np.radians(5.0), view_az, nb)[0] == \
        pytest.approx([1.0, 0.0])
    assert morphed_positions(xy, shift, view, np.radians(350.0), view_az, nb)[0] == \
        pytest.approx([0.0, -1.0])
    # Beyond the neighbour the features stay where the neighbour is.
    assert morphed_positions(xy, shift, view, np.radians(30.0), view_az, nb)[0] == \
        pytest.approx([4.0, 0.0])


def test_morphed_positions_over_the_sphere_add_the_elevation_move():
    xy = np.zeros((1, 2))
    shift = np.zeros((1, 4, 2))
    shift[0] = [[4.0, 0.0], [0.0, 0.0], [0.0, 6.0], [0.0, -6.0]]
    view_az, view_el = np.radians([0.0, 20.0, 0.0]), np.radians([0.0, 0.0, 30.0])
    nb = np.array([[1, -1, 2, -1], [-1, 0, -1, -1], [-1, -1, -1, 0]])
    moved = morphed_positions(xy, shift, np.array([0]), np.radians(5.0), view_az, nb,
                              elevation=np.radians(10.0), view_elevation=view_el)
    assert moved[0] == pytest.approx([1.0, 2.0])
    # Below the lowest ring there is no neighbour to move toward.
    below = morphed_positions(xy, shift, np.array([0]), 0.0, view_az, nb,
                              elevation=np.radians(-10.0), view_elevation=view_el)
    assert below[0] == pytest.approx([0.0, 0.0])
    with pytest.raises(ValueError, match="view_elevation"):
        morphed_positions(xy, shift, np.array([0]), 0.0, view_az, nb)


def _distance(model_feats, truth: np.ndarray) -> float:
    """Weighted mean distance from the model's features to the nearest true edge."""
    return float(np.average(cKDTree(truth).query(model_feats.xy)[0], weights=model_feats.weight))


def test_the_morphed_model_looks_like_the_views_between(draw):
    # Trained every 40 degrees; halfway between the training views the
    # morphed features lie nearer the edges of the real view there than the
    # blend of the two neighbours does.
    az = np.radians(np.arange(0, 360, 40))
    images = [draw(a) for a in az]
    boxes = np.array([object_box(im) for im in images])
    plain = PoseEstimator().fit(images, az, boxes=boxes)
    morphed = PoseEstimator(morph_views=True).fit(images, az, boxes=boxes)
    assert morphed.model_.shift is not None and plain.model_.shift is None
    kw = {"viewpoint_kappa": plain.viewpoint_kappa_, "k1_cutoff": 0.1}
    d_plain, d_morph = [], []
    for between in az + np.radians(20.0):
        view = draw(between)
        box = object_box(view)
        edges = replace(plain.edges, max_test_features=None)
        truth = normalize_features(extract_edges(view, edges, training=False),
                                   center=box[:2] + (box[2:] - 1) / 2, scale=1.0).xy
        d_plain.append(_distance(viewpoint_features(plain.model_, between, 0.0, **kw), truth))
        d_morph.append(_distance(viewpoint_features(morphed.model_, between, 0.0, **kw), truth))
    assert np.mean(d_morph) < 0.85 * np.mean(d_plain)
    # At a training view its own features do not move.
    at = viewpoint_features(morphed.model_, az[1], 0.0, **kw)
    own = viewpoint_features(plain.model_, az[1], 0.0, **kw)
    np.testing.assert_allclose(at.xy, own.xy)


def test_morphed_model_file_round_trip(tmp_path, synthetic_training):
    images, az, boxes = synthetic_training
    est = PoseEstimator(morph_views=True).fit(images[::2], az[::2], boxes=boxes[::2])
    est.save(tmp_path / "m.npz")
    loaded = PoseEstimator.load(tmp_path / "m.npz")
    assert np.array_equal(loaded.model_.shift, est.model_.shift)
    assert np.array_equal(loaded.model_.view_neighbour, est.model_.view_neighbour)
    assert loaded.estimate(images[1]).best == est.estimate(images[1]).best


def test_model_file_refuses_a_shift_of_the_wrong_shape(tmp_path, synthetic_training):
    from dataclasses import replace

    from posevote.model.modelfile import save_model

    images, az, boxes = synthetic_training
    est = PoseEstimator(morph_views=True).fit(images[::2], az[::2], boxes=boxes[::2])
    bad = replace(est.model_, shift=est.model_.shift[1:])
    from posevote.estimator import params_to_json
    from posevote.model.training import TrainedModel

    save_model(tmp_path / "bad.npz", TrainedModel(model=bad, full_model=bad,
                                                  viewpoint_kappa=est.viewpoint_kappa_),
               params_to_json(est.get_params(deep=False)))
    with pytest.raises(ValueError, match="bad.npz.*(inconsistent array shapes|declares shape)"):
        PoseEstimator.load(tmp_path / "bad.npz")


def test_a_morphed_model_blends_its_views_wider(synthetic_training):
    from posevote.model.density import MORPH_BANDWIDTH
    from posevote.model.kernels import kappa_for_width

    images, az, boxes = synthetic_training
    plain = PoseEstimator().fit(images, az, boxes=boxes)
    morphed = PoseEstimator(morph_views=True).fit(images, az, boxes=boxes)
    spacing = np.radians(20.0)
    assert plain.viewpoint_kappa_ == pytest.approx(kappa_for_width(0.5 * spacing), rel=1e-6)
    assert morphed.viewpoint_kappa_ == pytest.approx(kappa_for_width(MORPH_BANDWIDTH * spacing),
                                                     rel=1e-6)


def test_a_pruned_morphed_category_model_round_trips(tmp_path, draw):
    # Two instances on one turntable each; the pruned centres move as their
    # members do, and the file keeps both the pruned and the full shifts.
    az = np.radians(np.arange(0, 360, 30))
    images = [draw(a) for a in az] + [draw(a, scale=0.9) for a in az]
    boxes = np.array([object_box(im) for im in images])
    names = ["a"] * len(az) + ["b"] * len(az)
    est = PoseEstimator(morph_views=True, prune="moderate").fit(
        images, np.r_[az, az], boxes=boxes, instances=names)
    assert est.model_.shift.shape == (est.model_.n_features, 2, 2)
    assert est.full_model_.shift.shape == (est.full_model_.n_features, 2, 2)
    # Views are paired within their own instance only.
    nb = est.full_model_.view_neighbour
    inst = est.full_model_.view_instance
    assert np.all(inst[nb[nb >= 0]] == inst[np.nonzero(nb >= 0)[0]])
    sub = est.full_model_.instance_model(1)
    assert sub.view_neighbour.min() >= 0 and sub.view_neighbour.max() < sub.n_views
    est.save(tmp_path / "cat.npz")
    loaded = PoseEstimator.load(tmp_path / "cat.npz")
    assert np.array_equal(loaded.model_.shift, est.model_.shift)
    assert np.array_equal(loaded.full_model_.shift, est.full_model_.shift)
