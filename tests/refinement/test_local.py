from dataclasses import replace

import numpy as np
import pytest

from posevote.refinement import find_modes, polish_pose, refine_mode
from posevote.refinement.local import profile_refine


@pytest.fixture(scope="module")
def scene(fitted_estimator, draw):
    from posevote.data import object_box

    est = fitted_estimator
    img = draw(np.radians(60.0), scale=1.05, inplane=np.radians(4.0), centre=(66.0, 61.0))
    probes, _ = est.probe(img)
    feats, shape = est._features(img)
    fine = est._maps(feats, shape, sigma=est.position_sigma)
    x, y, w, h = object_box(img)
    return est, probes, fine, (x + (w - 1) / 2, y + (h - 1) / 2)


def test_polish_recovers_a_perturbed_pose(scene):
    est, probes, fine, _ = scene
    kw = dict(viewpoint_kappa=est.viewpoint_kappa_, k1_cutoff=est.k1_cutoff)

    start = refine_mode(probes, find_modes(probes)[0], fit=False)
    good = polish_pose(start, est.model_, fine, **kw)
    nudged = replace(good, position=(good.position[0] + 3.0, good.position[1] - 2.0),
                     scale=good.scale * 1.04)
    again = polish_pose(nudged, est.model_, fine, **kw)
    assert again.score == pytest.approx(good.score, abs=0.02)
    assert np.hypot(again.position[0] - good.position[0],
                    again.position[1] - good.position[1]) < 1.5
    assert again.scale == pytest.approx(good.scale, rel=0.02)


def test_profile_refine_lands_between_training_views(scene):
    est, probes, fine, centre = scene
    modes = find_modes(probes)
    hyp = profile_refine(probes, modes[0], est.model_, fine,
                         viewpoint_kappa=est.viewpoint_kappa_, k1_cutoff=est.k1_cutoff)
    assert hyp.refined
    assert abs(hyp.azimuth_deg - 60.0) < 10.0
    assert hyp.position == pytest.approx(centre, abs=3.0)
    anchor = refine_mode(probes, modes[0], fit=False)
    held = profile_refine(probes, modes[0], est.model_, fine, scale_margin=0.02,
                          viewpoint_kappa=est.viewpoint_kappa_, k1_cutoff=est.k1_cutoff)
    assert abs(np.log(held.scale / anchor.scale)) <= 0.02 + 1e-9


def test_start_near_keeps_to_the_mode_object():
    from posevote.inference import ProbeSet
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
    kw = dict(viewpoint_kappa=est.viewpoint_kappa_, k1_cutoff=est.k1_cutoff)
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


def test_rank_refined_orders_the_refined_modes_by_their_new_scores():
    from posevote.refinement.local import rank_refined
    from posevote.results import Hypothesis

    def hyp(azimuth_deg, score):
        return Hypothesis(azimuth=np.radians(azimuth_deg), elevation=0.0, inplane=0.0, scale=1.0,
                          position=(0.0, 0.0), box=(0.0, 0.0, 1.0, 1.0), score=score,
                          refined=False)

    modes = [hyp(0, 0.9), hyp(90, 0.8), hyp(180, 0.7), hyp(270, 0.6)]
    new_scores = {0: 0.5, 1: 0.95, 2: 0.6, 3: 0.65}
    seen = []

    def refine(k, h):
        seen.append(k)
        return replace(h, score=new_scores[k], refined=True)

    ranked = rank_refined(modes, refine, 3)
    assert seen == [0, 1, 2]
    seen.clear()
    assert [round(h.azimuth_deg) for h in ranked] == [90, 180, 0, 270]
    assert [h.refined for h in ranked] == [True, True, True, False]
    assert rank_refined(modes, refine, 1)[0].score == 0.5
    everything = rank_refined(modes, refine, 10)
    assert [round(h.azimuth_deg) for h in everything] == [90, 270, 180, 0]


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


def test_rescale_anchor_finds_the_scale_in_object_units(synthetic_training, draw):
    from posevote import PoseEstimator
    from posevote.data import object_box
    from posevote.inference.voting import scaled_features
    from posevote.refinement.local import rescale_anchor

    images, az, boxes = synthetic_training
    est = PoseEstimator(scale_range=(0.7, 1.3), scale_steps=5, object_kernel=True,
                        chance_correction=True).fit(images, az, boxes=boxes)
    img = draw(np.radians(40.0), scale=1.15, centre=(64.0, 64.0), size=160)
    probes, feats = est.probe(img)
    shape = img.shape[:2]
    maps = [est._maps(*scaled_features(feats, shape, float(s)), sigma=est.position_sigma,
                      scale=float(s)) for s in probes.scale]
    kw = dict(viewpoint_kappa=est.viewpoint_kappa_, k1_cutoff=est.k1_cutoff)
    mode = find_modes(probes)[0]
    anchor, s = rescale_anchor(probes, mode, est.model_, maps, **kw)
    assert anchor.scale == pytest.approx(1.15, rel=0.06)
    assert abs(np.log(probes.scale[s] / 1.15)) <= 0.5 * np.log(1.3 / 0.7) / 4 + 1e-9
    x, y, w, h = object_box(img)
    assert anchor.position == pytest.approx((x + (w - 1) / 2, y + (h - 1) / 2), abs=3.0)
    with pytest.raises(ValueError, match="one TestMaps per scale"):
        rescale_anchor(probes, mode, est.model_, maps[:2], **kw)


def test_interpolate_alignment_between_the_bracketing_views():
    from posevote.refinement.local import interpolate_alignment
    from posevote.results import Hypothesis

    def pose(az_deg, inplane_deg, scale, u, v):
        return Hypothesis(azimuth=np.radians(az_deg), elevation=0.0, inplane=np.radians(inplane_deg),
                          scale=scale, position=(u, v), box=(0.0, 0.0, 1.0, 1.0), score=1.0,
                          refined=False)

    views = np.radians([340.0, 0.0, 20.0, 40.0])
    aligned = [pose(340, 0, 1.0, 0, 0), pose(0, 350, 1.0, 10, 20), pose(20, 10, 4.0, 20, 40),
               pose(40, 0, 1.0, 0, 0)]
    # a quarter of the way from 0 to 20 degrees: across the wrap of the in-plane angle
    alpha, scale, (u, v) = interpolate_alignment(np.radians(5.0), views, aligned)
    assert np.degrees(alpha) == pytest.approx(-5.0)
    assert scale == pytest.approx(np.sqrt(2.0))  # log-linear: 4 ** 0.25
    assert (u, v) == pytest.approx((12.5, 25.0))
    # across the azimuth wrap, between 340 and 0 degrees
    _, _, (u, _) = interpolate_alignment(np.radians(350.0), views, aligned)
    assert u == pytest.approx(5.0)
    # outside the viewpoints: nothing to interpolate
    assert interpolate_alignment(np.radians(90.0), views[1:3], aligned[1:3]) is None


def test_profile_refine_interpolated_alignment_is_scored(scene):
    est, probes, fine, centre = scene
    modes = find_modes(probes)
    kw = dict(viewpoint_kappa=est.viewpoint_kappa_, k1_cutoff=est.k1_cutoff)
    hyp = profile_refine(probes, modes[0], est.model_, fine, interpolate=True, **kw)
    assert hyp.refined and abs(hyp.azimuth_deg - 60.0) < 10.0
    assert hyp.position == pytest.approx(centre, abs=3.0)
    from posevote.refinement.local import score_pose

    assert score_pose(hyp, est.model_, fine, **kw).score == pytest.approx(hyp.score)
