"""Stage 2: features become the training density psi (Eqs. 1-4)."""

from posevote.model.density import (
    PoseModel,
    build_model,
    image_density,
    pose_likelihood,
    viewpoint_weights,
)
from posevote.model.modelfile import FORMAT_VERSION, load_model, save_model
from posevote.model.weights import feature_weights

__all__ = ["FORMAT_VERSION", "PoseModel", "build_model", "feature_weights", "load_model",
           "pose_likelihood", "save_model", "image_density", "viewpoint_weights"]
