"""The estimate as named steps: what each preset runs, switches that are their step's own,
what training is asked for, and the state the steps hand on."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from posevote import PoseEstimator, pipeline
from posevote.appearance import AppearanceOptions
from posevote.pipeline import STEPS, Built, Settings, active_steps, artefacts, describe
from posevote.presets import PRESETS
from posevote.recognition import RecognitionOptions
from posevote.templates import TemplateOptions


def _settings(preset: str = "cluttered", **overrides) -> Settings:
    return Settings.of(PoseEstimator.from_preset(preset, **overrides).get_params(deep=False))


def _names(settings: Settings) -> list[str]:
    return [s.name for s in active_steps(settings)]


def test_each_preset_runs_its_steps_in_order():
    assert {name: _names(_settings(name)) for name in PRESETS} == {
        "default": ["search", "modes", "fit", "rescale", "recognise", "outline", "reject",
                    "probabilities", "place"],
        "cluttered": ["search", "rerank by template", "modes", "fit", "local refinement",
                      "half-turn", "share scale", "recognise", "outline", "reject",
                      "probabilities", "place"],
        "turntable": ["search", "modes", "fit", "local refinement", "recognise", "outline",
                      "reject", "probabilities", "place"],
        "category": ["search", "verify", "modes", "fit", "recognise", "appearance", "reject",
                     "probabilities", "place"]}
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
    assert artefacts(_settings("default")) == frozenset()
    assert artefacts(_settings("cluttered")) == {"templates"}
    assert artefacts(_settings("category")) == {"appearance", "ranked probes"}
    # The local refinement weighs by the templates: it asks for them alone.
    only_weigh = TemplateOptions(rerank=False, half_turn=False)
    assert artefacts(_settings("cluttered", templates=only_weigh)) == {"templates"}
    assert artefacts(_settings("cluttered", templates=only_weigh, refine__local=None)) == set()
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
