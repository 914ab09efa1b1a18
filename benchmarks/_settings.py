"""``NAME=VALUE`` estimator settings given on the benchmarks' command lines."""

from __future__ import annotations

import ast
from collections.abc import Iterable
from typing import Any


def parse_settings(items: Iterable[str]) -> dict[str, Any]:
    """``["a=1", "b=(2, 3)"]`` -> ``{"a": 1, "b": (2, 3)}`` (values as Python literals)."""
    out: dict[str, Any] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"expected NAME=VALUE, got {item!r}")
        out[name.strip()] = ast.literal_eval(value)
    return out
