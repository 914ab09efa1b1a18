"""posevote: continuous 3D pose of objects in single images, by probabilistic voting.

An implementation of Teney & Piater, "Continuous Pose Estimation in 2D Images
at Instance and Category Levels" (CRV 2013). The data flow follows the
subpackages: ``data`` -> ``features`` -> ``model`` -> ``inference`` ->
``refinement`` -> ``evaluation``; :class:`PoseEstimator` ties them together
and :mod:`posevote.presets` names the tuned configurations.
"""

from pathlib import Path
from typing import Any

from posevote._kernels import refresh_kernel_cache

__all__ = ["Camera", "Hypothesis", "NotFittedError", "PoseEstimate", "PoseEstimator",
           "__version__"]
__version__ = "0.1.0"

_EXPORTS = {"PoseEstimator": "posevote.estimator", "NotFittedError": "posevote._errors",
            "Hypothesis": "posevote.results", "PoseEstimate": "posevote.results",
            "Camera": "posevote.camera"}

# Before any kernel is loaded: a cached caller of a changed kernel would run the old one.
refresh_kernel_cache(Path(__file__).parent)


def __getattr__(name: str) -> Any:
    # Imported on first use, so that `posevote --help` loads none of the stages.
    if name in _EXPORTS:
        import importlib

        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'posevote' has no attribute {name!r}")
