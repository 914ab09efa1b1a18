"""Appearance refinement of the best mode: its box regressed, its viewpoint the nearest view's.

Beyond the paper, for dense training views of a category in full frames
(the ``category`` preset). The edge votes find the object and tell its
front from its back; the HOG descriptor of a well-placed box pins the
viewpoint down. The best mode's box is moved toward the object by the box
regressions (:mod:`posevote.appearance.model`), or, after the verification,
the verified box is kept (the appearance chose it among the candidates);
then the viewpoint becomes that of the training view whose descriptor is
nearest, among those within :data:`APPEARANCE_WINDOW_DEG` of the estimate.
How much nearer those views are than the half-turned ones is the estimate's
front/back evidence (:func:`front_back_share`), which its probability reads.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from posevote.appearance import AppearanceOptions
from posevote.appearance.descriptors import box_descriptor
from posevote.appearance.verify import (
    jittered_nearest_view,
    nearest_view,
    regress_described,
    views_within,
)
from posevote.geometry import box_centre, viewing_direction
from posevote.model.density import PoseModel
from posevote.model.training import AppearanceModel
from posevote.results import Hypothesis

#: The training views within this angle of the estimate compete for the
#: nearest descriptor: front/back confusions are left to the edges (the
#: nearest view of all lost on epfl-cv; docs/DEFAULTS.md).
APPEARANCE_WINDOW_DEG = 45.0


def appearance_refine(hypothesis: Hypothesis, image: NDArray[np.floating], model: PoseModel,
                      appearance: AppearanceModel, options: AppearanceOptions, *,
                      verified_box: tuple[float, float, float, float] | None = None
                      ) -> Hypothesis:
    """The mode in its regressed (or verified) box, its viewpoint the nearest training view's.

    Parameters
    ----------
    hypothesis : Hypothesis
        The best mode.
    image : ndarray, shape (H, W)
        The grey test image.
    model : PoseModel
        The searched model (its training viewpoints).
    appearance : AppearanceModel
    options : AppearanceOptions
    verified_box : (x, y, w, h), optional
        The verification winner's regressed box, kept as is.

    Returns
    -------
    Hypothesis
    """
    if appearance.regressor is None:
        raise ValueError("the appearance refinement needs the box regression, which this "
                         "model lacks; retrain it")
    window = appearance.window
    if verified_box is not None:
        box, d = verified_box, box_descriptor(image, verified_box, window)
    else:
        box, d = regress_described(image, hypothesis.box,
                                   box_descriptor(image, hypothesis.box, window),
                                   appearance.regressor, hypothesis.azimuth, window=window)
    scale = hypothesis.scale * box[3] / hypothesis.box[3] if hypothesis.box[3] > 0 \
        else hypothesis.scale
    out = replace(hypothesis, box=box, position=box_centre(box), scale=scale)
    if d is None:
        return out
    direction = viewing_direction(hypothesis.azimuth, hypothesis.elevation)
    limit = np.radians(APPEARANCE_WINDOW_DEG)
    if options.jitter > 0:
        k = jittered_nearest_view(image, box, appearance.descriptors, model.view_directions(),
                                  direction, window=limit, descriptor_window=window,
                                  fraction=options.jitter)
    else:
        k = nearest_view(d, appearance.descriptors, model.view_directions(), direction,
                         window=limit)
    if k is None:
        return out
    return replace(out, azimuth=float(model.view_azimuth[k]),
                   elevation=float(model.view_elevation[k]))


def front_back_share(hypothesis: Hypothesis, image: NDArray[np.floating], model: PoseModel,
                     appearance: AppearanceModel) -> float | None:
    """How much more the mode's box looks like its side of the object than the other:
    ``sigmoid(d_back - d_front)``.

    ``d_front`` is the squared HOG distance from the box's descriptor to the
    nearest training view within :data:`APPEARANCE_WINDOW_DEG` of the mode's
    viewpoint, ``d_back`` to the nearest within that angle of its half-turn.
    The edge votes' profile tells a car's front from its back poorly; this
    share ranks the category's flips last (``benchmarks/calibrate_probability.py``).

    Returns
    -------
    float or None
        The share in (0, 1); None when the box cannot be described or no
        training view lies near either side.
    """
    d = box_descriptor(image, hypothesis.box, appearance.window)
    if d is None:
        return None
    views = model.view_directions()
    limit = np.radians(APPEARANCE_WINDOW_DEG)
    front = views_within(views, viewing_direction(hypothesis.azimuth, hypothesis.elevation),
                         limit)
    back = views_within(views, viewing_direction(hypothesis.azimuth + np.pi,
                                                 hypothesis.elevation), limit)
    if len(front) == 0 or len(back) == 0:
        return None
    ref = appearance.descriptors
    sq = np.einsum("ij,ij->i", ref, ref) - 2.0 * (ref @ d)
    margin = float(sq[back].min() - sq[front].min())
    return float(1.0 / (1.0 + np.exp(-np.clip(margin, -50.0, 50.0))))
