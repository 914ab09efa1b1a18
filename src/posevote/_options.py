"""The base of the estimator's option groups: frozen, self-validating, compact repr.

Each stage owns one group (``EdgeOptions``, ``SearchOptions``, ...), a
frozen keyword-only dataclass that checks its fields when it is built, so
a bad value is refused where it is written, naming the group, the field and
the accepted range.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import math
import re
from typing import Any, ClassVar, TypeVar

import numpy as np


class Options:
    """Mixin of the option groups: validation helpers, a repr of what differs, JSON."""

    __dataclass_fields__: ClassVar[dict[str, dataclasses.Field[Any]]]

    def _fail(self, name: str, expected: str, value: Any) -> None:
        raise ValueError(f"{type(self).__name__}.{name} must be {expected}, got {value!r}")

    def _number(self, name: str, *, low: float = -math.inf, high: float = math.inf,
                low_open: bool = False, high_open: bool = False, optional: bool = False,
                integer: bool = False) -> None:
        """Check field ``name``: a finite (integer) number within the bounds (or None)."""
        value = getattr(self, name)
        if value is None and optional:
            return
        kinds: tuple[type, ...] = (int, np.integer) if integer else (int, float, np.integer,
                                                                       np.floating)
        ok = isinstance(value, kinds) and not isinstance(value, (bool, np.bool_))
        ok = ok and math.isfinite(float(value))
        ok = ok and (value > low if low_open else value >= low)
        ok = ok and (value < high if high_open else value <= high)
        if not ok:
            lo = "(" if low_open else "["
            hi = ")" if high_open else "]"
            kind = "an integer" if integer else "a finite number"
            bounds = f"{lo}{low:g}, {high:g}{hi}"
            self._fail(name, f"{kind} in {bounds}" + (" or None" if optional else ""), value)
        # One type per field whatever the source (an int from JSON, a numpy scalar).
        object.__setattr__(self, name, int(value) if integer else float(value))

    def _flag(self, name: str) -> None:
        if not isinstance(getattr(self, name), (bool, np.bool_)):
            self._fail(name, "True or False", getattr(self, name))
        object.__setattr__(self, name, bool(getattr(self, name)))

    def _pair(self, name: str) -> tuple[float, float]:
        """Check field ``name``: a pair of finite numbers, low <= high; returns it."""
        value = getattr(self, name)
        if isinstance(value, (str, bytes, dict)):
            self._fail(name, "a pair of numbers (low, high)", value)
        try:
            low, high = (float(v) for v in value)
        except (TypeError, ValueError):
            self._fail(name, "a pair of numbers (low, high)", value)
        if not (math.isfinite(low) and math.isfinite(high) and low <= high):
            self._fail(name, "a pair of finite numbers with low <= high", value)
        object.__setattr__(self, name, (low, high))
        return low, high

    def __repr__(self) -> str:
        changed = [f"{f.name}={getattr(self, f.name)!r}" for f in dataclasses.fields(self)
                   if getattr(self, f.name) != f.default]
        return f"{type(self).__name__}({', '.join(changed)})"

    def to_dict(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict (tuples as lists)."""
        return {f.name: (list(v) if isinstance(v, tuple) else v)
                for f in dataclasses.fields(self) for v in [getattr(self, f.name)]}

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, where: str = "") -> Any:
        """The group from :meth:`to_dict`'s output; unknown keys raise ``ValueError``."""
        if not isinstance(data, dict):
            raise ValueError(f"{where}{cls.__name__} must be a mapping of its fields, "
                             f"got {data!r}")
        names = {f.name: f for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - set(names))
        if unknown:
            raise ValueError(f"{where}unknown {cls.__name__} field(s) {', '.join(unknown)}; "
                             f"valid: {', '.join(names)}")
        values = {k: (tuple(v) if isinstance(v, list) else v) for k, v in data.items()}
        return cls(**values)


#: The longest value a ``NAME=VALUE`` setting may have (the parser's memory grows with it).
MAX_SETTING_CHARS = 1000


def parse_setting(text: str) -> Any:
    """A ``NAME=VALUE`` setting's value as written on a command line: a Python literal
    (``5``, ``(0.8, 1.2)``, ``None``), else one bare word as a string (``template``).

    Raises
    ------
    ValueError
        For anything else (``(1,``, ``a b``).
    """
    text = text.strip()
    if len(text) > MAX_SETTING_CHARS:
        raise ValueError(f"a value of {len(text):,} characters; a setting takes at most "
                         f"{MAX_SETTING_CHARS:,}")
    try:
        return ast.literal_eval(text)
    except (MemoryError, RecursionError):
        raise ValueError(f"{text[:40]!r}... nests too deep to read") from None
    except (ValueError, SyntaxError):
        if re.fullmatch(r"[A-Za-z_][A-Za-z0-9_.-]*", text):
            return text
        raise ValueError(f"{text!r} is neither a Python literal (number, True/False, None, "
                         "tuple, quoted string) nor a word") from None


def params_to_json(params: dict[str, Any]) -> dict[str, Any]:
    """Parameters as JSON-ready values: option groups (and other dataclasses) as dicts."""
    out: dict[str, Any] = {}
    for name, value in params.items():
        if isinstance(value, Options):
            value = value.to_dict()
        elif dataclasses.is_dataclass(value) and not isinstance(value, type):
            value = dataclasses.asdict(value)
        out[name] = value
    return out


def params_from_json(params: dict[str, Any], groups: dict[str, type],
                     valid: list[str]) -> dict[str, Any]:
    """The inverse of :func:`params_to_json`: dicts under a group's name become that group.

    Raises
    ------
    ValueError
        On a name not in ``valid``, or a group's unknown or bad field.
    """
    unknown = sorted(set(params) - set(valid))
    if unknown:
        raise ValueError(f"unknown parameter(s) {', '.join(unknown)}")
    out: dict[str, Any] = {}
    for name, value in params.items():
        cls = groups.get(name)
        if cls is not None and isinstance(value, dict):
            value = cls.from_dict(value, where=f"{name}: ") if issubclass(cls, Options) \
                else cls(**value)
        out[name] = value
    return out


_P = TypeVar("_P", bound="GroupedParams")


class GroupedParams:
    """scikit-learn's parameter contract for parameters that are option groups.

    ``get_params(deep=True)`` also lists every group field as
    ``group__field``, and ``set_params`` takes those keys (a frozen group is
    replaced by a copy with the field changed); ``repr`` shows what differs
    from the defaults. The parameters are those of ``__init__``; ``_groups``
    maps each grouped parameter to its option class.
    """

    _groups: ClassVar[dict[str, type[Options]]] = {}

    @classmethod
    def _param_names(cls) -> list[str]:
        return [n for n in inspect.signature(cls.__init__).parameters if n != "self"]

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """The parameters; with ``deep``, also every group field as ``group__field``."""
        out = {name: getattr(self, name) for name in self._param_names()}
        if deep:
            for name, value in list(out.items()):
                if isinstance(value, Options):
                    out.update({f"{name}__{f.name}": getattr(value, f.name)
                                for f in dataclasses.fields(value)})
        return out

    def set_params(self: _P, **params: Any) -> _P:
        """Set parameters (``name=value``, or ``group__field=value`` inside a group).

        Raises
        ------
        ValueError
            On an unknown name, a field of a group that is off (None), or a
            value its group refuses.
        """
        valid = self._param_names()
        for key, value in params.items():
            name, _, field = key.partition("__")
            if name not in valid:
                raise ValueError(f"unknown parameter {key!r}; valid: {', '.join(valid)}")
            if not field:
                setattr(self, name, value)
                continue
            group = getattr(self, name)
            if not isinstance(group, Options):
                kind = self._groups[name].__name__ if name in self._groups else "..."
                raise ValueError(f"{key!r}: {name} is {group!r}; set {name}={kind}(...) first")
            fields = [f.name for f in dataclasses.fields(group)]
            if field not in fields:
                raise ValueError(f"unknown parameter {key!r}; {type(group).__name__} has "
                                 f"{', '.join(fields)}")
            setattr(self, name, dataclasses.replace(group, **{field: value}))
        return self

    def __repr__(self) -> str:
        defaults = type(self)()
        changed = [f"{n}={v!r}" for n, v in self.get_params(deep=False).items()
                   if v != getattr(defaults, n)]
        return f"{type(self).__name__}({', '.join(changed)})"
