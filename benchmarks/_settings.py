"""``NAME=VALUE`` estimator settings given on the benchmarks' command lines.

``group.field=VALUE`` sets one field of an option group (``search.scale_steps=5``);
the result is a dict of :meth:`posevote.PoseEstimator.set_params` keys.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from posevote._options import parse_setting


def parse_settings(items: Iterable[str]) -> dict[str, Any]:
    """``["a=1", "search.b=(2, 3)", "search.c=d"]`` -> ``{"a": 1, "search__b": (2, 3),
    "search__c": "d"}`` (:func:`posevote._options.parse_setting`)."""
    out: dict[str, Any] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"expected NAME=VALUE, got {item!r}")
        out[name.strip().replace(".", "__")] = parse_setting(value)
    return out
