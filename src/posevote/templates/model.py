"""Each training view's grey appearance, upright and at a fixed size, for the template re-ranking.

Beyond the paper. The voting search ranks probes by the edges they explain;
on dense textures the clutter explains as many edges as the object does. The
object's own grey levels tell them apart: each training view keeps a small
template of its box (:data:`TEMPLATE_SIDE` pixels across its diagonal, its
in-plane angle undone, NaN outside its mask and its image), blurred by
:data:`TEMPLATE_BLUR` template pixels. :mod:`posevote.templates.match`
compares the test image with it under each of the search's best probes.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from posevote.features.edges import box_mask
from posevote.geometry import box_centre
from posevote.model.density import PoseModel

#: Template side, pixels: the view's box diagonal fits across it, so that any
#: in-plane angle of the box stays inside.
TEMPLATE_SIDE = 96
#: Blur of the image before it is sampled, in template pixels (here and on the
#: test image): tolerance to the search grid's steps and to viewpoints between
#: training views.
TEMPLATE_BLUR = 0.5


def template_frame(centre: ArrayLike, cell: ArrayLike, angle: ArrayLike) -> NDArray[np.float64]:
    """The 2 x 3 affine maps from template pixels to image pixels.

    Template pixel ``q`` lands at ``centre + cell * R(angle) (q - (T - 1) / 2)``:
    the template's centre on ``centre``, ``cell`` image pixels per template
    pixel, turned by ``angle`` (image convention, as
    :func:`posevote.geometry.rotate_points`). ``centre`` of shape (..., 2) and
    ``cell`` and ``angle`` broadcast with its leading shape give maps of
    shape (..., 2, 3).
    """
    centre = np.asarray(centre, dtype=np.float64)
    scaled = np.asarray(cell, dtype=np.float64)[..., None, None]
    c, s = np.cos(angle), np.sin(angle)
    linear = scaled * np.stack([np.stack([c, -s], axis=-1), np.stack([s, c], axis=-1)], axis=-2)
    half = (TEMPLATE_SIDE - 1) / 2.0
    shift = centre - half * linear.sum(axis=-1)
    return np.concatenate([linear, shift[..., None]], axis=-1)


def in_template(image: ArrayLike, frame: NDArray[np.float64]) -> NDArray[np.float32]:
    """``image`` resampled onto a template's pixels under ``frame``
    (:func:`template_frame`), bilinear, the border extended."""
    return np.asarray(cv2.warpAffine(np.asarray(image, dtype=np.float32), frame,
                                     (TEMPLATE_SIDE, TEMPLATE_SIDE),
                                     flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                     borderMode=cv2.BORDER_REPLICATE), dtype=np.float32)


def view_template(image: NDArray[np.floating], box: NDArray[np.float64],
                  mask: NDArray[np.bool_] | None, inplane: float
                  ) -> tuple[NDArray[np.float16], float]:
    """A training view's template and its pixel size in the view's pixels.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        The grey training image.
    box : ndarray, shape (4,)
        The object's box ``(x, y, w, h)``; its centre is the reference point.
    mask : ndarray of bool, shape (H, W), or None
        The object's pixels (None: the whole box).
    inplane : float
        The view's in-plane angle, radians (undone: the template is upright).

    Returns
    -------
    template : ndarray of float16, shape (TEMPLATE_SIDE, TEMPLATE_SIDE)
        Grey levels; NaN outside the mask, the box or the image.
    cell : float
        Image pixels per template pixel.
    """
    cell = float(np.hypot(box[2], box[3])) / TEMPLATE_SIDE
    frame = template_frame(box_centre(box), cell, inplane)
    blurred = cv2.GaussianBlur(np.asarray(image, dtype=np.float32), (0, 0), TEMPLATE_BLUR * cell)
    grey = in_template(blurred, frame)
    region = box_mask(image.shape, box, margin=0.0)
    if mask is not None:
        region &= mask
    inside = cv2.warpAffine(region.astype(np.float32), frame, (TEMPLATE_SIDE, TEMPLATE_SIDE),
                            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=0.0) > 0.99
    return np.where(inside, grey, np.nan).astype(np.float16), cell


class TemplateCollector:
    """Keeps each training view's template while ``fit`` reads the views (a
    :class:`~posevote.model.training.ViewCollector`): the model's ``view_template``
    and ``view_template_cell``."""

    def __init__(self, boxes: NDArray[np.float64]) -> None:
        k = len(boxes)
        self.templates = np.empty((k, TEMPLATE_SIDE, TEMPLATE_SIDE), dtype=np.float16)
        self.cells = np.zeros(k)

    def read(self, image: NDArray[np.float64], box: NDArray[np.float64],
             mask: NDArray[np.bool_] | None, pose: NDArray[np.float64]
             ) -> tuple[NDArray[np.float16], float]:
        """The view's template and its cell (:func:`view_template`), in the reading thread."""
        return view_template(image, box, mask, float(pose[2]))

    def add(self, index: int, read: tuple[NDArray[np.float16], float], box: NDArray[np.float64],
            pose: NDArray[np.float64]) -> None:
        self.templates[index], self.cells[index] = read

    def with_earlier(self, full: PoseModel, size: NDArray[np.float64]) -> None:
        """The templates of the views ``full`` learnt first, their cells at each view's
        training size (``size`` per instance)."""
        if full.view_template is None or full.view_template_cell is None:
            raise ValueError("the model holds no templates to extend")
        self.templates = np.concatenate([full.view_template, self.templates])
        self.cells = np.concatenate([full.view_template_cell * size[full.view_instance],
                                     self.cells])

    def onto_model(self, model: PoseModel, scales: NDArray[np.float64]) -> PoseModel:
        """The model with the templates, their cells in reference pixels (as the features)."""
        return replace(model, view_template=self.templates, view_template_cell=self.cells / scales)

    def learnt(self, sizes: NDArray[np.float64], n_threads: int) -> dict[str, object]:
        """Nothing apart from the model."""
        return {}
