"""Stage 0: images and pose-annotated training sets."""

from posevote.data.images import as_gray_float, read_bgr8, read_image, read_mask
from posevote.data.toy import toy_views
from posevote.data.training_set import (
    TrainingSet,
    object_box,
    object_mask,
    read_coil,
    read_epfl,
    read_poses_csv,
    write_poses_csv,
)

__all__ = [
    "TrainingSet",
    "as_gray_float",
    "object_box",
    "object_mask",
    "read_coil",
    "read_epfl",
    "read_bgr8",
    "read_image",
    "read_mask",
    "read_poses_csv",
    "toy_views",
    "write_poses_csv",
]
