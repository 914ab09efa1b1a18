"""``NAME=VALUE`` estimator settings given on the benchmarks' command lines.

``group.field=VALUE`` sets one field of an option group (``search.scale_steps=5``);
the result is a dict of :meth:`posevote.PoseEstimator.set_params` keys.
"""

from __future__ import annotations

import ast
from collections.abc import Iterable
from typing import Any


def parse_settings(items: Iterable[str]) -> dict[str, Any]:
    """``["a=1", "search.b=(2, 3)", "search.c=d"]`` -> ``{"a": 1, "search__b": (2, 3),
    "search__c": "d"}`` (Python literals; anything else a string)."""
    out: dict[str, Any] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"expected NAME=VALUE, got {item!r}")
        try:
            parsed = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            parsed = value.strip()          # a bare word: a string (search.rerank=template)
        out[name.strip().replace(".", "__")] = parsed
    return out
