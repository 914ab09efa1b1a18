"""posevote: continuous 3D pose of objects in single images, by probabilistic voting.

An implementation of Teney & Piater, "Continuous Pose Estimation in 2D Images
at Instance and Category Levels" (CRV 2013). The data flow follows the
subpackages: ``data`` -> ``features`` -> ``model`` -> ``inference`` ->
``refinement`` -> ``evaluation``; :class:`PoseEstimator` ties them together.
"""

from posevote.estimator import NotFittedError, PoseEstimator
from posevote.results import Hypothesis, PoseEstimate

__all__ = ["Hypothesis", "NotFittedError", "PoseEstimate", "PoseEstimator", "__version__"]
__version__ = "0.1.0"
