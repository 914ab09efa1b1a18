"""Named presets: each builds a valid estimator and says where it was chosen."""

from __future__ import annotations

import pytest

from posevote import PoseEstimator
from posevote.presets import PRESETS, get_preset, nearest_preset


def test_the_four_presets_and_their_provenance():
    assert set(PRESETS) >= {"default", "cluttered", "turntable", "category"}
    for name, preset in PRESETS.items():
        assert preset.name == name and preset.description and preset.chosen_on
        assert preset.script.startswith("benchmarks/") and preset.measured
        est = PoseEstimator.from_preset(name)
        defaults = PoseEstimator().get_params(deep=False)
        assert nearest_preset(est.get_params(deep=False), defaults) == {"name": name,
                                                                        "overrides": {}}


def test_presets_differ_where_they_should():
    default, clutter = PRESETS["default"], PoseEstimator.from_preset("cluttered")
    assert set(default.params) == {"min_score", "search", "refine"}
    assert clutter.refine.local == "profile"
    # The keypoint step where it helped (docs/DEFAULTS.md), not on the turntable.
    assert default.params["refine"].keypoints and clutter.refine.keypoints
    assert not PoseEstimator.from_preset("turntable").refine.keypoints
    # Every preset rejects by default (benchmarks/default_thresholds.py) and calibrates its
    # probability (benchmarks/calibrate_probability.py).
    assert all(PoseEstimator.from_preset(name).min_score > 0.0 for name in PRESETS)
    assert all(PoseEstimator.from_preset(name).search.calibration != (1.0, 0.0, 0.0)
               for name in PRESETS)
    assert clutter.search.inplane_range_deg == (-30.0, 30.0)
    turntable = PoseEstimator.from_preset("turntable")
    assert turntable.morph_views and turntable.search.viewpoint_subdivisions == 2
    category = PoseEstimator.from_preset("category")
    assert category.appearance is not None and category.recognition.search is False


def test_overrides_and_unknown_names():
    est = PoseEstimator.from_preset("category", appearance=None, search__scale_steps=4)
    assert est.appearance is None and est.search.scale_steps == 4
    assert est.search.viewpoint_step_deg == 10.0
    with pytest.raises(ValueError, match="unknown preset 'nope'"):
        get_preset("nope")


def test_the_nearest_preset_names_what_differs():
    est = PoseEstimator.from_preset("turntable", max_modes=2, search__scale_steps=7)
    found = nearest_preset(est.get_params(deep=False), PoseEstimator().get_params(deep=False))
    assert found["name"] == "turntable" and found["overrides"]["max_modes"] == 2
    assert found["overrides"]["search"]["scale_steps"] == 7
