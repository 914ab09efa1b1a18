"""posevote's own exception types."""

from __future__ import annotations

import functools
from typing import Any


@functools.cache
def not_fitted_error() -> type[Exception]:
    """``NotFittedError``: a subclass of scikit-learn's, raised before fit() or load().

    Built on first use: scikit-learn's import takes most of a second, which
    a plain estimate never pays.
    """
    from sklearn.exceptions import NotFittedError as Base

    return type("NotFittedError", (Base,), {
        "__doc__": "Raised when an estimator is used before fit() or load().",
        "__module__": "posevote"})


def __getattr__(name: str) -> Any:
    if name == "NotFittedError":
        return not_fitted_error()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
