"""Each training view's keypoints: SIFT's positions and descriptors inside its box.

Training keeps every view's keypoints in the features' frame (from the view's
reference point, upright, reference pixels) with their 128-byte descriptors;
:mod:`posevote.keypoints.refine` matches a test image's against them.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
from numpy.typing import NDArray

from posevote.features.edges import EdgeFeatures, box_mask, normalize_features
from posevote.geometry import box_centre
from posevote.model.density import PoseModel

#: The most keypoints kept of one view or one test box (SIFT's strongest).
MAX_KEYPOINTS = 500
#: Length of a SIFT descriptor.
DESCRIPTOR_LENGTH = 128


def detect_keypoints(image: NDArray[np.floating], mask: NDArray[np.bool_] | None = None, *,
                     limit: int = MAX_KEYPOINTS
                     ) -> tuple[NDArray[np.float64], NDArray[np.uint8]]:
    """SIFT keypoints of a grey image in [0, 1] (only where ``mask`` is True; at most
    ``limit``, the strongest).

    Returns
    -------
    xy : ndarray, shape (N, 2)
        Positions ``(u, v)``, pixels.
    descriptors : ndarray of uint8, shape (N, 128)
        Their descriptors (SIFT's are whole numbers within 0-255).
    """
    grey = np.clip(np.rint(np.asarray(image, dtype=np.float64) * 255.0), 0, 255).astype(np.uint8)
    sift = cv2.SIFT_create(nfeatures=limit)  # type: ignore[attr-defined]
    found, desc = sift.detectAndCompute(
        grey, None if mask is None else mask.astype(np.uint8) * 255)
    if desc is None or not found:
        return np.zeros((0, 2)), np.zeros((0, DESCRIPTOR_LENGTH), dtype=np.uint8)
    xy = np.array([k.pt for k in found], dtype=np.float64).reshape(-1, 2)
    return xy, np.clip(np.rint(desc), 0, 255).astype(np.uint8)


class KeypointCollector:
    """Keeps each training view's keypoints while ``fit`` reads the views (a
    :class:`~posevote.model.training.ViewCollector`): the model's ``keypoint_xy``,
    ``keypoint_descriptor`` and ``keypoint_view``."""

    def __init__(self, boxes: NDArray[np.float64]) -> None:
        self.found: list[tuple[NDArray[np.float64], NDArray[np.uint8]]] = [
            (np.zeros((0, 2)), np.zeros((0, DESCRIPTOR_LENGTH), dtype=np.uint8))] * len(boxes)
        self.earlier: tuple[NDArray[np.float64], NDArray[np.uint8], NDArray[np.int64]] | None \
            = None
        self.n_earlier = 0

    def read(self, image: NDArray[np.float64], box: NDArray[np.float64],
             mask: NDArray[np.bool_] | None, pose: NDArray[np.float64]
             ) -> tuple[NDArray[np.float64], NDArray[np.uint8]]:
        """The view's keypoints inside its box (and mask), upright from its box centre, view
        pixels; in the reading thread."""
        region = box_mask(image.shape, box, margin=0.0)
        if mask is not None:
            region &= mask
        xy, desc = detect_keypoints(image, region)
        upright = normalize_features(EdgeFeatures(xy=xy, theta=np.zeros(len(xy))),
                                     center=np.asarray(box_centre(box)), scale=1.0,
                                     inplane=float(pose[2])).xy
        return upright, desc

    def add(self, index: int, read: tuple[NDArray[np.float64], NDArray[np.uint8]],
            box: NDArray[np.float64], pose: NDArray[np.float64]) -> None:
        self.found[index] = read

    def with_earlier(self, full: PoseModel, size: NDArray[np.float64]) -> None:
        """The keypoints of the views ``full`` learnt first, at each view's training size
        (``size`` per instance)."""
        if full.keypoint_xy is None or full.keypoint_descriptor is None \
                or full.keypoint_view is None:
            raise ValueError("the model holds no keypoints to extend")
        self.earlier = (full.keypoint_xy * size[full.view_instance[full.keypoint_view]][:, None],
                        full.keypoint_descriptor, full.keypoint_view)
        self.n_earlier = full.n_views

    def onto_model(self, model: PoseModel, scales: NDArray[np.float64]) -> PoseModel:
        """The model with the keypoints, in reference pixels (as the features)."""
        xy = [kp for kp, _ in self.found]
        views = np.repeat(np.arange(len(xy)) + self.n_earlier, [len(p) for p in xy])
        all_xy = np.vstack([np.zeros((0, 2)), *xy])
        desc = np.vstack([np.zeros((0, DESCRIPTOR_LENGTH), dtype=np.uint8),
                          *(d for _, d in self.found)])
        if self.earlier is not None:
            all_xy = np.vstack([self.earlier[0], all_xy])
            desc = np.vstack([self.earlier[1], desc])
            views = np.concatenate([self.earlier[2], views])
        views = views.astype(np.int64)
        return replace(model, keypoint_xy=all_xy / scales[views][:, None],
                       keypoint_descriptor=desc, keypoint_view=views)

    def learnt(self, sizes: NDArray[np.float64], n_threads: int) -> dict[str, object]:
        """Nothing apart from the model."""
        return {}
