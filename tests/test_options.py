"""The option groups' base: validation messages, compact repr, JSON round trip."""

from __future__ import annotations

import math

import pytest

from posevote.appearance import AppearanceOptions
from posevote.features.edges import EdgeOptions
from posevote.inference.setup import SearchOptions
from posevote.model.kernels import KernelOptions
from posevote.recognition import RecognitionOptions

GROUPS = (EdgeOptions, KernelOptions, SearchOptions, RecognitionOptions, AppearanceOptions)


@pytest.mark.parametrize("group", GROUPS)
def test_defaults_round_trip_through_json(group):
    default = group()
    assert group.from_dict(default.to_dict()) == default
    assert repr(default) == f"{group.__name__}()"
    with pytest.raises(ValueError, match=f"unknown {group.__name__} field"):
        group.from_dict({"nonsense": 1})


@pytest.mark.parametrize(("build", "message"), [
    (lambda: EdgeOptions(sigma=math.inf), r"EdgeOptions.sigma must be a finite number in \(0, 20\]"),
    (lambda: EdgeOptions(thresholds=(0.05, 0.02)), "EdgeOptions.thresholds"),
    (lambda: EdgeOptions(thresholds="high"), "EdgeOptions.thresholds must be a pair"),
    (lambda: EdgeOptions(max_train_features=True), "EdgeOptions.max_train_features must be an integer"),
    (lambda: KernelOptions(position_sigma=float("nan")), "KernelOptions.position_sigma"),
    (lambda: SearchOptions(object_kernel="yes"), "SearchOptions.object_kernel must be True or False"),
    (lambda: SearchOptions(scale_range=(1.0, math.inf)), "SearchOptions.scale_range"),
    (lambda: SearchOptions(scale_range=(1.0, 1e6)), "SearchOptions.scale_range"),
])
def test_bad_values_name_the_group_and_field(build, message):
    with pytest.raises(ValueError, match=message):
        build()


def test_groups_are_frozen():
    import dataclasses

    with pytest.raises(dataclasses.FrozenInstanceError):
        SearchOptions().scale_steps = 5  # type: ignore[misc]


def test_settings_read_literals_and_bare_words():
    from posevote._options import parse_setting

    assert parse_setting(" 5 ") == 5 and parse_setting("(0.8, 1.2)") == (0.8, 1.2)
    assert parse_setting("None") is None and parse_setting("'template'") == "template"
    assert parse_setting("template") == "template" and parse_setting("nan") == "nan"
    for bad in ("(1,", "a b", ""):
        with pytest.raises(ValueError, match="neither a Python literal"):
            parse_setting(bad)
