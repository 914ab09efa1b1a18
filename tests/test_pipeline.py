"""The estimate as named steps: what each preset runs, switches that are their step's own,
what training is asked for, and the state the steps hand on."""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np
import pytest

from posevote import PoseEstimator, pipeline
from posevote.appearance import AppearanceOptions
from posevote.pipeline import STEPS, Built, Settings, active_steps, artefacts, describe
from posevote.presets import PRESETS
from posevote.recognition import RecognitionOptions
from posevote.refinement.probability import calibrated
from posevote.templates import TemplateOptions


def _settings(preset: str = "cluttered", **overrides) -> Settings:
    return Settings.of(PoseEstimator.from_preset(preset, **overrides).get_params(deep=False))


def _names(settings: Settings) -> list[str]:
    return [s.name for s in active_steps(settings)]


def test_each_preset_runs_its_steps_in_order():
    assert {name: _names(_settings(name)) for name in PRESETS} == {
        "default": ["search", "modes", "fit", "rescale", "recognise", "keypoints", "outline",
                    "reject", "probabilities", "lookalike", "place"],
        "cluttered": ["search", "rerank by template", "modes", "fit", "local refinement",
                      "half-turn", "share scale", "recognise", "keypoints", "outline",
                      "contrast", "reject", "probabilities", "lookalike", "place"],
        "turntable": ["search", "modes", "fit", "local refinement", "recognise", "outline",
                      "reject", "probabilities", "lookalike", "place"],
        "category": ["search", "verify", "modes", "fit", "recognise", "appearance", "reject",
                     "probabilities", "lookalike", "place"]}
    assert describe(_settings("cluttered"))[4] == "local refinement (profile)"
    assert describe(_settings("default"))[3] == "rescale [one instance]"


# Each switchable step, and the settings that switch it on and off (nothing else changes).
FLIPS = {
    "rerank by coverage": ({"search__rerank": "coverage"}, {"search__rerank": None}),
    "rerank by template": ({"templates__rerank": True}, {"templates__rerank": False}),
    "verify": ({"appearance": AppearanceOptions()}, {"appearance": AppearanceOptions(candidates=0)}),
    "fit": ({"refine__fit": True}, {"refine__fit": False}),
    "rescale": ({"refine__rescale": True}, {"refine__rescale": False}),
    "local refinement": ({"refine__local": "polish"}, {"refine__local": None}),
    "half-turn": ({"templates__half_turn": True}, {"templates__half_turn": False}),
    "share scale": ({"refine__share_scale": True}, {"refine__share_scale": False}),
    "recognise": ({"recognition": RecognitionOptions()}, {"recognition": None}),
    "appearance": ({"appearance": AppearanceOptions(candidates=0)}, {"appearance": None}),
    "outline": ({"refine__outline": True}, {"refine__outline": False}),
    "contrast": ({"search__contrast": True}, {"search__contrast": False}),
    "keypoints": ({"refine__keypoints": True}, {"refine__keypoints": False}),
}


@pytest.mark.parametrize("step", sorted(FLIPS))
@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_a_switch_turns_its_own_step_and_no_other(step, preset):
    on, off = FLIPS[step]
    base = {"templates": TemplateOptions()} if "templates__" in next(iter(on)) else {}
    first, second = _names(_settings(preset, **base, **on)), _names(_settings(preset, **base, **off))
    assert step in first and step not in second
    assert [n for n in first if n != step] == second


def test_every_step_has_a_flip_or_always_runs():
    assert {s.name for s in STEPS if s.switch.startswith("always")} | set(FLIPS) == \
        {s.name for s in STEPS}


def test_training_learns_what_the_steps_ask_for(synthetic_training):
    # Every preset's lookalike step asks for the views' likeness to other sides.
    assert artefacts(_settings("default")) == {"keypoints", "lookalike"}
    assert artefacts(_settings("cluttered")) == {"templates", "keypoints", "lookalike"}
    assert artefacts(_settings("category")) == {"appearance", "ranked probes", "lookalike"}
    assert "keypoints" in artefacts(_settings("turntable", refine__keypoints=True))
    # The local refinement weighs by the templates: it asks for them alone.
    only_weigh = TemplateOptions(rerank=False, half_turn=False)
    assert artefacts(_settings("cluttered", templates=only_weigh)) == {"templates", "keypoints",
                                                                       "lookalike"}
    assert artefacts(_settings("cluttered", templates=only_weigh, refine__local=None,
                               refine__keypoints=False)) == {"lookalike"}
    images, az, boxes = synthetic_training
    asked = PoseEstimator(templates=only_weigh).set_params(refine__local="profile").fit(
        images, az, boxes=boxes)
    assert asked.model_.view_template is not None
    plain = PoseEstimator(templates=only_weigh).fit(images, az, boxes=boxes)
    assert plain.model_.view_template is None


def test_the_steps_hand_on_what_they_make(fitted_estimator, draw):
    est = fitted_estimator
    settings = Settings.of(est.get_params(deep=False))
    steps = active_steps(settings)
    image = draw(np.radians(50.0))
    state, _ = est._begin(image, "rgb")
    searched = pipeline.run(state, steps[:1])
    assert searched.probes is not None and searched.hypotheses == ()
    moded = pipeline.run(searched, steps[1:2])
    assert len(moded.modes) == len(moded.hypotheses) >= 1
    assert not any(h.refined for h in moded.hypotheses)
    done = pipeline.run(moded, steps[2:])
    assert done.hypotheses[0].refined
    assert pipeline.result(done, 0.0).best == est.estimate(image).best


def test_the_reject_step_keeps_a_detection_score_at_min_score(fitted_estimator, draw):
    # A contrast is never below 0 (the chance floor): min_score 0 keeps every mode.
    state, _ = fitted_estimator._begin(draw(np.radians(50.0)), "rgb")
    found = pipeline.run(state, active_steps(state.settings)[:2]).hypotheses[0]
    hyps = [replace(found, contrast=0.0), replace(found, contrast=2.0)]

    def kept(min_score):
        settings = replace(state.settings, min_score=min_score)
        done = pipeline.reject(replace(state.with_hypotheses(hyps), settings=settings))
        return [h.contrast for h in done.hypotheses], done.top_score

    assert kept(0.0) == ([0.0, 2.0], 2.0)
    assert kept(2.0) == ([2.0], 2.0)
    assert kept(2.5) == ([], 2.0)


def test_a_shared_artefact_is_built_once_and_only_when_read():
    calls = []
    built = Built(lambda: calls.append(1) or len(calls))
    assert calls == []
    assert built() == 1 and built() == 1 and calls == [1]


def test_the_narrow_maps_follow_the_features(fitted_estimator, draw):
    state, _ = fitted_estimator._begin(draw(np.radians(50.0)), "rgb")
    fewer = state.with_features(state.features.select(np.arange(len(state.features)) % 2 == 0))
    assert len(fewer.narrow().xy) == len(fewer.features) < len(state.narrow().xy)
    assert replace(state, modes=(1,)).narrow() is state.narrow()


def test_settings_are_checked():
    base = PoseEstimator().get_params(deep=False)
    for change, error in (({"max_modes": 0}, ValueError), ({"refine": "profile"}, TypeError),
                          ({"morph_views": "yes"}, ValueError), ({"prune": "hard"}, ValueError)):
        with pytest.raises(error):
            Settings.of({**base, **change})


# --- image levels -------------------------------------------------------------


def test_an_estimate_at_a_level_comes_back_in_the_images_pixels():
    from posevote.results import Hypothesis, PoseEstimate

    h = Hypothesis(azimuth=0.1, elevation=0.0, inplane=0.0, scale=1.0, position=(49.5, 9.5),
                   box=(39.5, -0.5, 20.0, 20.0), score=0.3, refined=True)
    back = pipeline.from_level(PoseEstimate(found=True, best=h, modes=(h,), top_score=0.3), 0.5)
    assert back.best.position == (99.5, 19.5) and back.best.scale == 2.0
    assert back.best.box == (79.5, -0.5, 40.0, 40.0) and back.modes == (back.best,)
    assert pipeline.from_level(PoseEstimate(found=False, best=None), 0.5).best is None


def test_a_levels_camera_sees_a_point_where_the_resized_image_has_it():
    from posevote.camera import Camera

    camera = Camera(fx=600.0, fy=610.0, cx=319.5, cy=239.5)
    point = np.array([0.05, -0.02, 0.8])
    u, v = camera.project(point)
    small = pipeline.level_camera(camera, 0.5)
    assert np.allclose(small.project(point), [(u + 0.5) * 0.5 - 0.5, (v + 0.5) * 0.5 - 0.5])
    assert pipeline.level_camera(None, 0.5) is None and pipeline.level_camera(camera, 1.0) is camera


def test_a_level_gets_its_share_of_the_frames_test_budget():
    from posevote.features.edges import EdgeOptions

    edges = EdgeOptions(max_test_features=2500)
    assert pipeline.level_edges(edges, (720, 1280), 0.5).max_test_features == 1875
    assert pipeline.level_edges(edges, (480, 640), 0.5).max_test_features == 625
    assert pipeline.level_edges(edges, (480, 640), 1.0) is edges
    none = EdgeOptions(max_test_features=None)
    assert pipeline.level_edges(none, (480, 640), 0.5) is none


def test_a_halved_level_finds_an_object_twice_the_scales_searched():
    import cv2

    from posevote.data import toy_views

    images, poses, boxes = toy_views(range(0, 360, 30))
    est = PoseEstimator(min_score=0.0).fit(images, poses, boxes=boxes)
    view = toy_views([60])[0][0]
    canvas = np.zeros((480, 640))
    canvas[30:286, 40:296] = cv2.resize(view, (256, 256), interpolation=cv2.INTER_LINEAR)
    alone = est.estimate(canvas)
    est.set_params(search__image_levels=(1.0, 0.5))
    both = est.estimate(canvas)
    assert both.top_score > alone.top_score
    assert both.best.scale == pytest.approx(2.0, rel=0.1)
    x, y, w, h = both.best.box
    assert abs(x + w / 2 - (40 + 2 * (boxes[2][0] + boxes[2][2] / 2))) < 12
    assert abs(np.degrees(both.best.azimuth) - 60) < 10
    # A crop under 640 x 480 is taken to be framed around its object: searched as given.
    crop = canvas[:320, :320]
    assert pipeline.image_levels(est._settings(), crop.shape) == (1.0,)
    est.set_params(search__image_levels=(1.0,))
    assert est.estimate(crop).top_score == est.set_params(
        search__image_levels=(1.0, 0.5)).estimate(crop).top_score


def test_a_level_over_one_maps_back_the_scale_only():
    from posevote.results import Hypothesis, PoseEstimate

    h = Hypothesis(azimuth=0.1, elevation=0.0, inplane=0.0, scale=1.0, position=(50.0, 10.0),
                   box=(39.5, -0.5, 20.0, 20.0), score=0.3, refined=True)
    back = pipeline.from_level(PoseEstimate(found=True, best=h, modes=(h,), top_score=0.3), 2.0)
    assert back.best.position == h.position and back.best.box == h.box
    assert back.best.scale == 0.5
    image = np.zeros((480, 640))
    assert pipeline.level_image(image, 2.0) is image
    from posevote.camera import Camera
    from posevote.features.edges import EdgeOptions

    camera = Camera(fx=600.0, fy=610.0, cx=319.5, cy=239.5)
    assert pipeline.level_camera(camera, 2.0) is camera
    edges = EdgeOptions(max_test_features=2500)
    assert pipeline.level_edges(edges, (720, 1280), 2.0) is edges


def test_a_shrunk_level_finds_an_object_half_the_scales_searched():
    import cv2

    from posevote.data import toy_views

    images, poses, boxes = toy_views(range(0, 360, 30))
    view = toy_views([60])[0][0]
    canvas = np.zeros((480, 640))
    canvas[200:264, 300:364] = cv2.resize(view, (64, 64), interpolation=cv2.INTER_AREA)
    from posevote.inference.setup import SearchOptions

    est = PoseEstimator(min_score=0.0, search=SearchOptions(image_levels=(2.0, 1.0)))
    est.fit(images, poses, boxes=boxes)
    assert [level for level, _ in est.shrunk_models_] == [2.0]
    small = est.shrunk_models_[0][1].full_model
    np.testing.assert_allclose(small.view_box, est.full_model_.view_box / 2)
    both = est.estimate(canvas)
    assert both.best.scale == pytest.approx(0.5, rel=0.1)
    x, y, w, h = both.best.box
    assert abs(x + w / 2 - (300 + (boxes[2][0] + boxes[2][2] / 2) / 2)) < 6
    assert abs(np.degrees(both.best.azimuth) - 60) < 15
    alone = est.set_params(search__image_levels=(1.0,)).estimate(canvas)
    assert both.top_score > alone.top_score
    # A level the model was not fitted with is refused, naming it.
    with pytest.raises(ValueError, match="image level 3 .* fit the model again"):
        est.set_params(search__image_levels=(3.0, 1.0)).estimate(canvas)


def test_the_levels_on_one_image_read_its_edges_keypoints_and_maps_once(monkeypatch):
    from posevote.data import toy_views
    from posevote.inference.setup import SearchOptions

    images, poses, boxes = toy_views(range(0, 360, 30))
    est = PoseEstimator(min_score=0.0, search=SearchOptions(image_levels=(2.0, 1.0, 0.5)),
                        refine=pipeline.RefineOptions(keypoints=True))
    est.fit(images, poses, boxes=boxes)
    canvas = np.zeros((480, 640))
    canvas[100:228, 200:328] = toy_views([60])[0][0]
    read: list[tuple[int, ...]] = []
    edges, keypoints = pipeline.extract_edges, pipeline.image_keypoints
    monkeypatch.setattr(pipeline, "extract_edges",
                        lambda image, *a, **k: read.append(image.shape) or edges(image, *a, **k))
    monkeypatch.setattr(pipeline, "image_keypoints",
                        lambda image: read.append(("keypoints", *image.shape)) or keypoints(image))
    narrow = pipeline.narrow_maps
    monkeypatch.setattr(pipeline, "narrow_maps", lambda features, shape, setup, **k: read.append(
        ("narrow", *shape)) or narrow(features, shape, setup, **k))
    est.estimate(canvas)
    assert sorted(read, key=str) == sorted([(480, 640), (240, 320), ("keypoints", 480, 640),
                                            ("keypoints", 240, 320), ("narrow", 480, 640),
                                            ("narrow", 240, 320)], key=str)


def test_image_levels_are_checked():
    from posevote.inference.setup import SearchOptions

    assert SearchOptions(image_levels=[0.5, 1.0]).image_levels == (1.0, 0.5)
    assert SearchOptions(image_levels=(1.0, 1.8)).image_levels == (1.8, 1.0)
    for bad in ((), (1.0, 1.0), (0.05,), (4.5,), (1.0, 0.8, 0.6, 0.4, 0.2), "1", (float("nan"),)):
        with pytest.raises(ValueError, match="image_levels"):
            SearchOptions(image_levels=bad)


def test_a_pose_the_keypoints_turn_keeps_the_found_one_next(fitted_estimator, draw, monkeypatch):
    est = copy.deepcopy(fitted_estimator).set_params(refine__keypoints=True, min_score=0.0)
    image = draw(np.radians(50.0))
    found = est.set_params(refine__keypoints=False).estimate(image)
    monkeypatch.setattr(pipeline, "keypoint_locate", lambda h, model, image, **kw: None)
    monkeypatch.setattr(pipeline, "keypoint_refine", lambda h, model, image, **kw: (
        replace(h, azimuth=float(np.mod(h.azimuth + np.pi, 2 * np.pi))), 0.9))
    turned = est.set_params(refine__keypoints=True).estimate(image)
    assert turned.best.azimuth == pytest.approx(np.mod(found.best.azimuth + np.pi, 2 * np.pi))
    assert turned.modes[1].azimuth == found.best.azimuth
    # The texture's share of the inliers is the share its probability reads.
    assert turned.best.probability == pytest.approx(
        calibrated(0.9, turned.best.score, est.search.calibration))
    assert len(turned.modes) <= est.max_modes


def test_a_pose_the_keypoints_locate_keeps_the_found_one_next(fitted_estimator, draw,
                                                               monkeypatch):
    est = copy.deepcopy(fitted_estimator).set_params(refine__keypoints=True, min_score=0.0)
    image = draw(np.radians(50.0))
    found = est.set_params(refine__keypoints=False).estimate(image)
    monkeypatch.setattr(pipeline, "keypoint_locate", lambda h, model, image, **kw: (
        replace(h, position=(h.position[0] + 3.0, h.position[1])), 0.8))
    monkeypatch.setattr(pipeline, "keypoint_refine", lambda h, model, image, **kw: (h, None))
    located = est.set_params(refine__keypoints=True).estimate(image)
    assert located.modes[1].position == found.best.position
    # Polished on the edges from where the texture put it (3 px off: back on the peak), its
    # side's share the texture's.
    np.testing.assert_allclose(located.best.position, found.best.position, atol=0.5)
    assert located.best.probability == pytest.approx(
        calibrated(0.8, located.best.score, est.search.calibration))


def test_the_keypoints_compare_one_instances_views_only(synthetic_training, draw, monkeypatch):
    images, az, boxes = synthetic_training
    other = [np.ascontiguousarray(np.asarray(i)[::-1]) for i in images]   # upside down
    est = PoseEstimator(refine=pipeline.RefineOptions(keypoints=True), recognition=None,
                        min_score=0.0).fit(list(images) + other, np.concatenate([az, az]),
                                           boxes=np.concatenate([boxes, boxes]),
                                           instances=["a"] * len(images) + ["b"] * len(images))
    seen = []
    monkeypatch.setattr(pipeline, "keypoint_refine",
                        lambda h, model, image, views=None, **kw: seen.append(views) or (h, None))
    est.estimate(draw(np.radians(50.0)))
    assert seen == []                  # several instances, none recognised: nothing compared
    est.set_params(recognition=RecognitionOptions())
    found = est.estimate(draw(np.radians(50.0)))
    half = len(images)
    assert found.instance == "a" and len(seen) == 1 and list(seen[0]) == list(range(half))
