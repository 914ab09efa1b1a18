from dataclasses import replace

import numpy as np
import pytest

from posevote.features.edges import EdgeFeatures, extract_edges
from posevote.inference.setup import SearchOptions, SearchSetup
from posevote.model.density import build_model
from posevote.model.kernels import K1_CUTOFF
from posevote.refinement.fitting import find_modes, refine_mode
from posevote.refinement.local import (
    in_frame,
    local_refine,
    polish_pose,
    probe_pose,
    profile_refine,
    refine_viewpoint,
    rescale_mode,
    unit_score,
)
from posevote.results import Hypothesis
from posevote.scoring.maps import scaled_features
from posevote.scoring.score import narrow_maps


@pytest.fixture(scope="module")
def scene(fitted_estimator, draw):
    from posevote.data import object_box

    est = fitted_estimator
    img = draw(np.radians(60.0), scale=1.05, inplane=np.radians(4.0), centre=(66.0, 61.0))
    probes, _ = est.probe(img)
    feats = extract_edges(img, est.edges, training=False)
    fine = narrow_maps(feats, img.shape, est.setup())
    x, y, w, h = object_box(img)
    return est, probes, fine, (x + (w - 1) / 2, y + (h - 1) / 2)


def test_polish_recovers_a_perturbed_pose(scene):
    est, probes, fine, _ = scene
    kw = dict(viewpoint_kappa=est.viewpoint_kappa_, k1_cutoff=K1_CUTOFF)

    start = refine_mode(probes, find_modes(probes)[0], fit=False)
    good = polish_pose(start, est.model_, fine, **kw)
    nudged = replace(good, position=(good.position[0] + 3.0, good.position[1] - 2.0),
                     scale=good.scale * 1.04)
    again = polish_pose(nudged, est.model_, fine, **kw)
    assert again.score == pytest.approx(good.score, abs=0.02)
    assert np.hypot(again.position[0] - good.position[0],
                    again.position[1] - good.position[1]) < 1.5
    assert again.scale == pytest.approx(good.scale, rel=0.02)


def test_rescale_mode_moves_only_the_scale_and_position(scene):
    est, probes, fine, centre = scene
    fitted = refine_mode(probes, find_modes(probes)[0], fit=True)
    good = polish_pose(fitted, est.model_, fine, turn=False, viewpoint_kappa=est.viewpoint_kappa_,
                       k1_cutoff=K1_CUTOFF)
    # A fit that read the scale 5% short and the position 2 px off.
    short = replace(fitted, scale=good.scale * 0.95,
                    position=(good.position[0] + 2.0, good.position[1] - 1.0))
    out = rescale_mode(short, est.model_, fine, est.setup())
    assert out.scale == pytest.approx(good.scale, rel=0.01)
    assert np.hypot(out.position[0] - good.position[0], out.position[1] - good.position[1]) < 1.0
    # The angles and the score are the fit's (min_score is calibrated on it).
    assert (out.azimuth, out.elevation, out.inplane, out.score) == (
        short.azimuth, short.elevation, short.inplane, short.score)
    assert out.box != short.box


def test_polish_on_a_subset_of_the_features_lands_near_the_full_polish(scene):
    est, probes, fine, _ = scene
    kw = dict(viewpoint_kappa=est.viewpoint_kappa_, k1_cutoff=K1_CUTOFF)
    start = refine_mode(probes, find_modes(probes)[0], fit=False)
    full = polish_pose(start, est.model_, fine, **kw)
    # No fewer features than the view has: the same polish.
    assert polish_pose(start, est.model_, fine, max_features=10**6, **kw) == full
    few = polish_pose(start, est.model_, fine, max_features=40, **kw)
    assert few != full
    assert np.hypot(few.position[0] - full.position[0],
                    few.position[1] - full.position[1]) < 1.5
    assert few.scale == pytest.approx(full.scale, rel=0.03)


def test_profile_refine_lands_between_training_views(scene):
    est, probes, fine, centre = scene
    modes = find_modes(probes)
    hyp = profile_refine(probes, modes[0], est.model_, fine,
                         viewpoint_kappa=est.viewpoint_kappa_, k1_cutoff=K1_CUTOFF)
    assert hyp.refined
    assert abs(hyp.azimuth_deg - 60.0) < 10.0
    assert hyp.position == pytest.approx(centre, abs=3.0)
    anchor = refine_mode(probes, modes[0], fit=False)
    held = profile_refine(probes, modes[0], est.model_, fine, scale_margin=0.02,
                          viewpoint_kappa=est.viewpoint_kappa_, k1_cutoff=K1_CUTOFF)
    assert abs(np.log(held.scale / anchor.scale)) <= 0.02 + 1e-9


def test_profile_refine_weighs_the_viewpoints_by_their_weight(scene):
    from posevote.refinement.fitting import neighbour_viewpoints

    est, probes, fine, _ = scene
    mode = find_modes(probes)[0]
    kw = dict(viewpoint_kappa=est.viewpoint_kappa_, k1_cutoff=K1_CUTOFF)
    plain = profile_refine(probes, mode, est.model_, fine, **kw)
    seen = []

    def flat(hyps):
        seen.append(len(hyps))
        return np.full(len(hyps), 0.5)

    # A correlation alike everywhere moves nothing; the pose returned is scored
    # as the profile's were.
    weighed = profile_refine(probes, mode, est.model_, fine, weigh=flat, **kw)
    assert weighed == replace(plain, score=plain.score * 0.5) and plain.refined
    assert seen == [len(neighbour_viewpoints(probes, mode, radius_steps=2.5)), 1]

    def ahead(hyps):
        # Only the views past the plain fit look like the object (the others keep a floor).
        return np.array([1.0 if np.sin(h.azimuth - plain.azimuth) > 0 else 0.01 for h in hyps])

    moved = profile_refine(probes, mode, est.model_, fine, weigh=ahead, **kw)
    assert np.sin(moved.azimuth - plain.azimuth) > np.sin(np.radians(1.0))


def test_start_near_keeps_to_the_mode_object():
    from posevote.inference.probes import ProbeSet
    from posevote.refinement.local import start_near

    # Viewpoint 1's best probe (score 0.9) sits on clutter far from the mode;
    # its second-best one (0.5) is on the mode's object.
    score = np.zeros((2, 1, 2))
    translation = np.zeros((2, 1, 2, 2))
    score[0, 0, 0], translation[0, 0, 0] = 0.8, (50.0, 50.0)
    score[1, 0, 0], translation[1, 0, 0] = 0.5, (54.0, 48.0)
    score[1, 0, 1], translation[1, 0, 1] = 0.9, (200.0, 30.0)
    probes = ProbeSet(azimuth=np.radians([0.0, 20.0]), elevation=np.zeros(2),
                      inplane=np.zeros(1), scale=np.array([1.0, 0.7]), score=score,
                      translation=translation, box=np.full((2, 2), 40.0))
    anchor = refine_mode(probes, 0, fit=False)
    start = start_near(probes, 1, anchor)
    assert start.position == (54.0, 48.0) and start.score == 0.5 and start.scale == 1.0
    assert start.azimuth == pytest.approx(np.radians(20.0))
    # With nothing on the object, the anchor's pose is carried to the viewpoint.
    probes.score[1, 0, 0] = 0.0
    probes.translation[1, 0, 0] = (120.0, 120.0)
    moved = start_near(probes, 1, anchor)
    assert moved.position == anchor.position and moved.scale == anchor.scale
    assert moved.azimuth == pytest.approx(np.radians(20.0))


def test_polish_keeps_the_scale_within_bounds(scene):
    est, probes, fine, _ = scene
    kw = dict(viewpoint_kappa=est.viewpoint_kappa_, k1_cutoff=K1_CUTOFF)
    start = refine_mode(probes, find_modes(probes)[0], fit=False)
    good = polish_pose(start, est.model_, fine, **kw)
    shrunk = replace(good, scale=good.scale * 0.85)
    free = polish_pose(shrunk, est.model_, fine, **kw)
    held = polish_pose(shrunk, est.model_, fine, scale_bounds=(0.8 * good.scale,
                                                               0.87 * good.scale), **kw)
    assert free.scale == pytest.approx(good.scale, rel=0.03)
    assert 0.8 * good.scale - 1e-9 <= held.scale <= 0.87 * good.scale + 1e-9
    # A start outside the bounds may stay where it is but not move farther out.
    outside = polish_pose(shrunk, est.model_, fine, scale_bounds=(0.95 * good.scale,
                                                                  1.05 * good.scale), **kw)
    assert outside.scale >= shrunk.scale - 1e-9


def test_in_frame_round_trip():
    from posevote.refinement.local import in_frame
    from posevote.results import Hypothesis

    h = Hypothesis(azimuth=0.3, elevation=0.1, inplane=0.2, scale=0.8, position=(40.0, 60.0),
                   box=(10.0, 20.0, 60.0, 80.0), score=0.5, refined=True)
    framed = in_frame(h, 2.0)
    assert framed.scale == 0.4 and framed.position == (20.0, 30.0)
    assert framed.box == (5.0, 10.0, 30.0, 40.0) and framed.inplane == h.inplane
    back = in_frame(framed, 0.5)
    assert back.position == h.position and back.box == h.box
    assert back.scale == pytest.approx(h.scale)


def _rescale_case(synthetic_training, draw):
    """An estimator searching 5 scales in object units, an image at scale 1.15, its probes,
    features and best mode."""
    from posevote import PoseEstimator

    images, az, boxes = synthetic_training
    est = PoseEstimator(search=SearchOptions(scale_range=(0.7, 1.3), scale_steps=5,
                                             object_kernel=True, chance_correction=True)
                        ).fit(images, az, boxes=boxes)
    img = draw(np.radians(40.0), scale=1.15, centre=(64.0, 64.0), size=160)
    probes, feats = est.probe(img)
    return est, img, probes, feats, find_modes(probes)[0]


def test_rescale_anchor_finds_the_scale_in_object_units(synthetic_training, draw):
    from posevote.data import object_box
    from posevote.refinement.local import rescale_anchor

    est, img, probes, feats, mode = _rescale_case(synthetic_training, draw)
    shape = img.shape[:2]
    anchor, s = rescale_anchor(probes, mode, est.model_, feats, shape, est.setup())
    assert anchor.scale == pytest.approx(1.15, rel=0.06)
    assert abs(np.log(probes.scale[s] / 1.15)) <= 0.5 * np.log(1.3 / 0.7) / 4 + 1e-9
    x, y, w, h = object_box(img)
    assert anchor.position == pytest.approx((x + (w - 1) / 2, y + (h - 1) / 2), abs=3.0)
    # Each scale's maps around its probe only: the same polish as on the whole image's.
    kw = dict(viewpoint_kappa=est.viewpoint_kappa_, k1_cutoff=K1_CUTOFF)
    factor = float(probes.scale[s])
    a = int(np.argmax(probes.score[mode, :, s]))
    start = in_frame(probe_pose(probes, mode, a, s), factor)
    half = 0.5 * float(np.median(np.diff(np.log(probes.scale))))
    whole = polish_pose(start, est.model_,
                        narrow_maps(*scaled_features(feats, shape, factor), est.setup(),
                                    scale=factor), **kw,
                        scale_bounds=(float(np.exp(-half)), float(np.exp(half))))
    assert in_frame(whole, 1.0 / factor).position == pytest.approx(anchor.position, abs=1e-6)
    with pytest.raises(ValueError, match="features and shape"):
        local_refine(probes, mode, anchor, est.model_, est.setup(), profile=True,
                     narrow=lambda: None, scale_step=0.1, object_units=True)


def test_compass_search_kernel_agrees_with_reference():
    from posevote.features import EdgeFeatures
    from posevote.refinement.local import _compass_search, compass_search_reference
    from posevote.scoring.maps import prepare_test
    from posevote.scoring.score import gather_score

    rng = np.random.default_rng(8)
    model_xy = rng.uniform(-25, 25, (120, 2))
    model_theta = rng.uniform(0, np.pi, 120)
    weight = np.full(120, 1 / 120)
    alpha, scale, t = 0.1, 1.05, np.array([62.0, 48.0])
    c, s = np.cos(alpha), np.sin(alpha)
    placed = scale * model_xy @ np.array([[c, s], [-s, c]]) + t
    maps = prepare_test(EdgeFeatures(xy=placed, theta=np.mod(model_theta + alpha, np.pi)),
                        (100, 130), position_sigma=2.0, orientation_kappa=8.0)
    start = np.array([0.05, np.log(1.0), 60.0, 50.0])
    unit = np.array([1 / 25, 1 / 25, 1.0, 1.0])
    bounds = np.array([-np.inf, np.inf])
    z, best, initial = _compass_search(maps.density, maps.frame, model_xy, model_theta, weight,
                                       start, unit, bounds, 8.0)
    z_ref, best_ref, initial_ref = compass_search_reference(maps, model_xy, model_theta, weight,
                                                            start, unit, bounds, 8.0)
    np.testing.assert_allclose(z, z_ref, atol=1e-9)
    assert best == pytest.approx(best_ref, rel=1e-9) and initial == pytest.approx(initial_ref)
    # It climbs to the true pose, and the score it reports is the score there.
    found = start + z * unit
    assert best > initial
    assert np.all(np.abs(found - [alpha, np.log(scale), *t]) <= [0.02, 0.02, 0.5, 0.5])
    assert best == pytest.approx(gather_score(maps.density, maps.frame, model_xy, model_theta,
                                              weight, found[0], np.exp(found[1]), found[2],
                                              found[3]))
    # Within its bounds.
    tight = np.array([-0.01, 0.01])
    z, *_ = _compass_search(maps.density, maps.frame, model_xy, model_theta, weight, start, unit,
                            tight, 8.0)
    assert abs(start[1] + z[1] * unit[1]) <= 0.01 + 1e-12 and np.all(np.abs(z) <= 8.0)
    # A unit of 0 holds that axis, in both.
    held = unit * [0.0, 1.0, 1.0, 1.0]
    z, best, _ = _compass_search(maps.density, maps.frame, model_xy, model_theta, weight, start,
                                 held, bounds, 8.0)
    z_ref, best_ref, _ = compass_search_reference(maps, model_xy, model_theta, weight, start,
                                                  held, bounds, 8.0)
    assert z[0] == 0.0 and z_ref[0] == 0.0
    np.testing.assert_allclose(z, z_ref, atol=1e-9)
    assert best == pytest.approx(best_ref, rel=1e-9) and best > initial


def test_rescale_anchor_weighs_each_scale_by_its_weight(synthetic_training, draw):
    from posevote.refinement.local import rescale_anchor

    est, img, probes, feats, mode = _rescale_case(synthetic_training, draw)
    args = (probes, mode, est.model_, feats, img.shape[:2], est.setup())
    plain, s = rescale_anchor(*args)
    seen = []

    def weigh(hyps):
        seen.append(len(hyps))
        # The edges' choice does not look like the object (a floor); the others do.
        return np.array([0.01 if abs(h.scale - plain.scale) < 1e-9 else 1.0 for h in hyps])

    weighed, s2 = rescale_anchor(*args, weigh=weigh)
    assert seen == [len(probes.scale)] and s2 != s
    assert rescale_anchor(*args, weigh=lambda hyps: np.ones(len(hyps)))[1] == s


def _square_scene(line_drawing, scale, position=(90.0, 90.0)):
    """A one-view model of a square with a cross, the view drawn at ``scale``, and a pose."""
    segments, square = line_drawing
    lines = square(20.0) + [([-12.0, 0.0], [12.0, 0.0]), ([0.0, -12.0], [0.0, 12.0])]
    view = segments(lines)
    model = build_model([EdgeFeatures(xy=view.xy + 50.0, theta=view.theta)],
                        poses=np.zeros((1, 3)), centers=np.full((1, 2), 50.0), scales=np.ones(1),
                        box_sizes=np.array([[40.0, 40.0]]), instances=[0],
                        instance_names=["toy"], reference_size=40.0)
    # Edge points 2 px apart in the image at any scale, as extracted.
    drawn = segments([(np.asarray(a) * scale, np.asarray(b) * scale) for a, b in lines])
    feats = EdgeFeatures(xy=drawn.xy + 90.0, theta=drawn.theta)
    setup = SearchSetup(options=SearchOptions(), position_sigma=2.0, edge_spacing=2.0,
                        viewpoint_kappa=10.0)
    side = 40.0 * scale
    pose = Hypothesis(azimuth=0.0, elevation=0.0, inplane=0.0, scale=scale, position=position,
                      box=(position[0] - side / 2, position[1] - side / 2, side, side),
                      score=1.0, refined=True)
    return model, feats, setup, pose


def test_unit_score_is_zero_on_clutter_at_every_scale(line_drawing):
    # Random edges explain a model only by chance, at any scale: above chance, 0.
    from posevote.features.edges import EdgeFeatures

    rng = np.random.default_rng(0)
    clutter = EdgeFeatures(xy=rng.uniform(0.0, 180.0, (3000, 2)),
                           theta=rng.uniform(0.0, np.pi, 3000))
    for scale in (0.7, 1.4):
        model, feats, setup, pose = _square_scene(line_drawing, scale)
        on = unit_score(pose, model, feats, (180, 180), setup)
        chance = [unit_score(replace(pose, position=tuple(rng.uniform(50.0, 130.0, 2))), model,
                             clutter, (180, 180), setup) for _ in range(20)]
        assert abs(np.mean(chance)) < 0.03
        assert on > 0.7


def test_unit_score_falls_off_the_object(line_drawing):
    model, feats, setup, pose = _square_scene(line_drawing, 1.0)
    on = unit_score(pose, model, feats, (180, 180), setup)
    off = unit_score(replace(pose, position=(30.0, 30.0)), model, feats, (180, 180), setup)
    assert off < 0.1 < on


def _rectangle(segments, azimuth, elevation):
    """A view whose edges move with the viewpoint (degrees): wider with the azimuth, its
    inner bar higher with the elevation."""
    w = 20.0 + 0.3 * azimuth
    c = [[-w, -20.0], [w, -20.0], [w, 20.0], [-w, 20.0]]
    bar = 0.3 * elevation
    return segments([(c[k], c[(k + 1) % 4]) for k in range(4)] + [([-w, bar], [w, bar])])


def _rectangle_sphere(segments):
    """The rectangle's views every 10 deg of azimuth and 7.5 deg of elevation, their model
    and a narrow kernel's setup."""
    grid = [(a, e) for a in range(-20, 21, 10) for e in np.arange(-15.0, 15.1, 7.5)]
    views = [_rectangle(segments, a, e) for a, e in grid]
    model = build_model([EdgeFeatures(xy=v.xy + 50.0, theta=v.theta) for v in views],
                        poses=np.radians([[a, e, 0.0] for a, e in grid]),
                        centers=np.full((len(grid), 2), 50.0), scales=np.ones(len(grid)),
                        box_sizes=np.full((len(grid), 2), 46.0), instances=[0] * len(grid),
                        instance_names=["toy"], reference_size=46.0)
    setup = SearchSetup(options=SearchOptions(), position_sigma=2.0, edge_spacing=2.0,
                        viewpoint_kappa=300.0)
    return views, model, setup


def test_refine_viewpoint_reads_the_viewpoint_between_training_views(line_drawing):
    segments, _ = line_drawing
    views, model, setup = _rectangle_sphere(segments)
    view = _rectangle(segments, 4.0, 3.0)
    maps = narrow_maps(EdgeFeatures(xy=view.xy + 80.0, theta=view.theta), (160, 160), setup)
    start = Hypothesis(azimuth=0.0, elevation=0.0, inplane=0.0, scale=1.0, position=(80.0, 80.0),
                       box=(57.0, 57.0, 46.0, 46.0), score=1.0, refined=True)
    found = refine_viewpoint(start, model, maps, setup, lambda poses: np.ones(len(poses)))
    assert np.degrees(found.azimuth) == pytest.approx(4.0, abs=1.5)
    assert np.degrees(found.elevation) == pytest.approx(3.0, abs=1.5)
    assert np.allclose(found.position, (80.0, 80.0), atol=1.0)
    # One elevation: the half-turn's viewpoint is left as it is polished.
    ring = build_model([EdgeFeatures(xy=v.xy + 50.0, theta=v.theta) for v in views[2::5]],
                       poses=np.radians([[a, 0.0, 0.0] for a in range(-20, 21, 10)]),
                       centers=np.full((5, 2), 50.0), scales=np.ones(5),
                       box_sizes=np.full((5, 2), 46.0), instances=[0] * 5,
                       instance_names=["toy"], reference_size=46.0)
    assert refine_viewpoint(start, ring, maps, setup, lambda poses: np.ones(len(poses))) is start


def test_refine_viewpoint_keeps_the_scale_within_its_bounds(line_drawing):
    segments, _ = line_drawing
    _, model, setup = _rectangle_sphere(segments)
    # The object at 0.6 of the starting pose's size: unbounded, the polishes shrink it.
    view = _rectangle(segments, 4.0, 3.0)
    maps = narrow_maps(EdgeFeatures(xy=0.6 * view.xy + 80.0, theta=view.theta), (160, 160),
                       setup)
    start = Hypothesis(azimuth=0.0, elevation=0.0, inplane=0.0, scale=1.0, position=(80.0, 80.0),
                       box=(57.0, 57.0, 46.0, 46.0), score=1.0, refined=True)
    free = refine_viewpoint(start, model, maps, setup, lambda poses: np.ones(len(poses)))
    assert free.scale < 0.85
    bounded = refine_viewpoint(start, model, maps, setup, lambda poses: np.ones(len(poses)),
                               scale_bounds=(0.85, 1.2))
    assert 0.85 - 1e-9 <= bounded.scale <= 1.2 + 1e-9
