"""Stage 1: images become edge-point features."""

from posevote.features.edges import (
    EdgeFeatures,
    box_mask,
    detect_edges,
    normalize_features,
)

__all__ = ["EdgeFeatures", "box_mask", "detect_edges", "normalize_features"]
