import numpy as np
import pytest

from posevote.features.edges import EdgeFeatures
from posevote.geometry import rotate_points
from posevote.inference.setup import SearchOptions, SearchSetup
from posevote.model.density import build_model
from posevote.model.kernels import K1_CUTOFF, ORIENTATION_KAPPA, orientation_kernel, position_kernel
from posevote.refinement.local import polish_pose
from posevote.refinement.share import (
    SHARE_SCALE_SPAN,
    edge_share,
    edge_shares,
    inside_pose,
    pose_features,
    share_scale,
)
from posevote.results import Hypothesis
from posevote.scoring.score import narrow_maps

_SETUP = SearchSetup(options=SearchOptions(), position_sigma=2.0, edge_spacing=2.0,
                     viewpoint_kappa=10.0)


def _cross(segments, arm):
    return segments([([-arm, 0.0], [arm, 0.0]), ([0.0, -arm], [0.0, arm])])


def _model(view, side=40.0):
    """One view, centred at (50, 50), with no outline: its box bounds it."""
    return build_model([EdgeFeatures(xy=view.xy + 50.0, theta=view.theta)],
                       poses=np.zeros((1, 3)), centers=np.full((1, 2), 50.0),
                       scales=np.ones(1), box_sizes=np.array([[side, side]]), instances=[0],
                       instance_names=["toy"], reference_size=side)


def _pose(scale, position=(80.0, 80.0)):
    return Hypothesis(azimuth=0.0, elevation=0.0, inplane=0.0, scale=scale, position=position,
                      box=(60.0, 60.0, 40.0, 40.0), score=0.5, refined=True)


def _maps(view):
    return narrow_maps(EdgeFeatures(xy=view.xy + 80.0, theta=view.theta), (160, 160), _SETUP)


def test_edge_share_counts_the_selected_edges_explained(line_drawing):
    segments, square = line_drawing
    face = segments(square(20.0) + [([-12.0, 0.0], [12.0, 0.0]), ([0.0, -12.0], [0.0, 12.0])])
    maps = _maps(face)
    everything = np.ones(len(maps.xy), dtype=bool)
    assert edge_share(_pose(1.0), _model(face), maps, everything, _SETUP) > 0.9
    # A plain square explains the face's outline and not its cross.
    plain = edge_share(_pose(1.0), _model(segments(square(20.0))), maps, everything, _SETUP)
    assert plain == pytest.approx(len(segments(square(20.0)).xy) / len(face.xy), abs=0.1)
    assert edge_share(_pose(1.0), _model(face), maps, np.zeros_like(everything), _SETUP) == 0.0


def _share_reference(pose, feats, maps, selected, scale, reach_sigmas=4.0):
    """Every pair of edges, no tree: the share at one scale."""
    sigma = maps.position_sigma
    xy = scale * rotate_points(feats.xy, pose.inplane) + np.asarray(pose.position)
    theta = np.mod(feats.theta + pose.inplane, np.pi)

    def density(at_xy, at_theta):
        sq = np.sum((at_xy[:, None, :] - xy[None, :, :]) ** 2, axis=2)
        k = position_kernel(sq, sigma) * orientation_kernel(at_theta[:, None] - theta[None, :],
                                                            ORIENTATION_KAPPA)
        return np.sum(np.where(sq <= (reach_sigmas * sigma) ** 2, k, 0.0), axis=1)

    own = np.arange(0, len(xy), max(1, len(xy) // 256))
    typical = np.median(density(xy[own], theta[own]))
    return np.mean(np.minimum(density(maps.xy[selected], maps.theta[selected]) / typical, 1.0))


def test_edge_shares_sum_every_pair_at_every_scale(line_drawing):
    segments, square = line_drawing
    # Sides off the 2 px grid: no pair of features lies exactly at the reach.
    view = segments(square(19.3) + [([-12.0, 3.0], [10.0, -5.0])])
    model = _model(view)
    rng = np.random.default_rng(0)
    image = EdgeFeatures(xy=np.concatenate([view.xy * 1.03 + 80.0, rng.uniform(50, 110, (60, 2))]),
                         theta=np.concatenate([view.theta, rng.uniform(0, np.pi, 60)]))
    maps = narrow_maps(image, (160, 160), _SETUP)
    pose = Hypothesis(azimuth=0.0, elevation=0.0, inplane=0.2, scale=1.0, position=(80.5, 79.0),
                      box=(60.0, 60.0, 40.0, 40.0), score=0.5, refined=True)
    selected = rng.random(len(maps.xy)) < 0.8
    feats = pose_features(pose, model, _SETUP)
    scales = [0.94, 1.0, 1.03, 1.06]
    got = edge_shares(pose, model, maps, selected, _SETUP, scales)
    want = [_share_reference(pose, feats, maps, selected, s) for s in scales]
    assert np.allclose(got, want, rtol=1e-9, atol=1e-12)
    assert len(set(np.round(got, 6))) == len(scales)
    assert edge_share(pose, model, maps, selected, _SETUP) == pytest.approx(want[1], rel=1e-9)


def test_inside_pose_uses_the_views_box_without_an_outline(line_drawing):
    segments, square = line_drawing
    model = _model(segments(square(20.0)))
    feats_box = np.array([40.0, 40.0])
    points = np.array([[80.0, 80.0], [99.0, 80.0], [101.0, 80.0], [80.0, 61.0], [80.0, 57.0]])
    feats = pose_features(_pose(1.0), model, _SETUP)
    assert np.allclose(feats.box, feats_box)
    inside = inside_pose(_pose(1.0), model, points, _SETUP, feats)
    assert inside.tolist() == [True, True, False, True, False]
    # 10% larger, the box reaches 22 px from the centre.
    assert inside_pose(_pose(1.1), model, points, _SETUP, feats).tolist() == [True] * 4 + [False]


def test_share_scale_keeps_the_right_scale_and_finds_it_nearby(line_drawing):
    segments, square = line_drawing
    face = segments(square(20.0) + square(12.0))
    model, maps = _model(face), _maps(face)
    for start in (1.0, 0.97, 1.03):
        found = share_scale(_pose(start), model, maps, _SETUP)
        assert found.scale == pytest.approx(1.0, abs=0.005)
        assert np.allclose(found.position, (80.0, 80.0), atol=0.5)
        assert found.score == 0.5 and found.refined


def test_share_scale_lets_the_image_edges_set_a_scale_the_score_cannot(line_drawing):
    # A short cross lies on a longer one at any scale: the narrow score alone
    # draws it in, and only the longer arms it leaves unexplained say it is too small.
    segments, _ = line_drawing
    model, maps = _model(_cross(segments, 12.0), side=24.0), _maps(_cross(segments, 16.0))
    kw = {"viewpoint_kappa": _SETUP.viewpoint_kappa, "k1_cutoff": K1_CUTOFF}
    assert polish_pose(_pose(1.0), model, maps, **kw).scale < 1.0
    found = share_scale(_pose(1.0), model, maps, _SETUP)
    assert found.scale > 1.0 + 0.7 * (SHARE_SCALE_SPAN - 1.0)
    assert found.scale <= SHARE_SCALE_SPAN + 1e-9


def test_share_scale_leaves_a_pose_with_nothing_to_explain(line_drawing):
    segments, square = line_drawing
    model = _model(segments(square(20.0)))
    far = _pose(1.0, position=(20.0, 20.0))
    maps = narrow_maps(EdgeFeatures(xy=segments(square(10.0)).xy + 130.0,
                                   theta=segments(square(10.0)).theta), (160, 160), _SETUP)
    assert share_scale(far, model, maps, _SETUP) is far
