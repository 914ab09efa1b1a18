"""The found pose checked against its half-turn (beyond the paper).

Seen from behind, an object often shows the outline it shows from the front,
and where one side carries fewer edges than the other (a plain back, a
detailed face) its edges are nearly a subset of the other side's. The
narrow score is the share of the model that the image explains, so the
plainer side placed over the other explains itself as fully as the right
pose does, and a search over a range of scales also finds the size where
its outline fits (a back framed larger than the face). What tells them apart is the other direction: the share
of the test edges inside the two poses' outlines that each pose's features
explain (:func:`~posevote.refinement.share.edge_share`).

:func:`half_turn` polishes the found pose's half-turn (azimuth plus 180
degrees, the elevation kept) from :data:`HALF_TURN_SCALES` times its scale,
keeps the polish whose narrow score times template correlation is highest,
reads its viewpoint and the found pose's between the training views alike
(:func:`~posevote.refinement.local.refine_viewpoint`, over the sphere; on a
turntable the found pose is polished on the same maps), and scores the two
by their narrow score above chance with the kernel in object units at each
one's own scale (:func:`~posevote.refinement.local.unit_score`: the side
shrunk onto the other's inner edges gains nothing from its size) times how
well the image matches their templates and their share of the test edges.
Over the sphere the match is the likeness of gradients
(:func:`~posevote.templates.match.gradient_similarity`: pooled over
cells, a small detail that sets the sides apart counts though drawn a pixel
or two off); on a turntable it is the grey-level correlation (the gradients
did worse on COIL's sparse views). The half-turn replaces the found pose where
it scores higher (``TemplateOptions.half_turn``; docs/DESIGN.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from posevote.features.edges import EdgeFeatures
from posevote.model.density import PoseModel
from posevote.refinement.local import PoseWeights, polish_pose, refine_viewpoint, unit_score
from posevote.refinement.share import edge_share, inside_pose, pose_features
from posevote.results import Hypothesis
from posevote.scoring.maps import TestMaps
from posevote.scoring.score import ScoreSetup, score_options

#: Scales, relative to the found pose's, that the half-turn's polishes start
#: from: a side framed differently is found at another size (docs/DEFAULTS.md).
HALF_TURN_SCALES = (0.85, 1.0, 1 / 0.85)


def _within_reach(pose: Hypothesis) -> tuple[float, float]:
    """The scales a pose's viewpoint reading may polish it to: two of
    :data:`HALF_TURN_SCALES`' steps either way, past what a polish moves a pose of
    ordinary size (one step bound those too), short of where a pose a few pixels
    across shrinks onto dense edges, on which a shrinking model's narrow score grows
    (docs/history/TRUST.md)."""
    low, high = min(HALF_TURN_SCALES), max(HALF_TURN_SCALES)
    return pose.scale * low**2, pose.scale * high**2


def half_turn(hypothesis: Hypothesis, model: PoseModel, maps: TestMaps, setup: ScoreSetup,
              weigh: PoseWeights, *,
              resemble: Callable[[Hypothesis], float], features: EdgeFeatures,
              shape: tuple[int, int]) -> tuple[Hypothesis, bool]:
    """The found pose, or its half-turn where that explains the image better.

    Parameters
    ----------
    hypothesis : Hypothesis
        The refined pose (image pixels).
    model : PoseModel
    maps : TestMaps
        The test image's narrow maps in image pixels
        (:func:`posevote.scoring.score.narrow_maps`).
    setup : ScoreSetup
    weigh : callable
        Each pose's correlation with the object's grey levels, floored
        (:func:`posevote.templates.match.correlation_weights`).
    resemble : callable
        How alike a pose's image gradients and its template's are
        (:func:`posevote.templates.match.gradient_similarity`).
    features : EdgeFeatures
        The test features, image pixels (the two poses' scores in object units).
    shape : (int, int)
        The image's shape.

    Returns
    -------
    Hypothesis
        The found pose (over the sphere its viewpoint read again, with
        ``hypothesis``'s score; else ``hypothesis`` itself), or the polished
        half-turn scored by its narrow score times its correlation (as the
        local refinement scores).
    bool
        Whether it is the half-turn.
    """
    opts = score_options(setup)
    # Over the sphere both sides' viewpoints are read between the training views
    # alike; a turntable's found pose was fitted on the search's finer grid.
    sphere = bool(np.ptp(model.view_elevation) > 0)
    found = (refine_viewpoint(hypothesis, model, maps, setup, weigh,
                              scale_bounds=_within_reach(hypothesis)) if sphere
             else polish_pose(hypothesis, model, maps, **opts))
    kept = replace(found, score=hypothesis.score) if sphere else hypothesis
    turned = float(np.mod(hypothesis.azimuth + np.pi, 2.0 * np.pi))
    candidates = [polish_pose(replace(hypothesis, azimuth=turned, scale=hypothesis.scale * f),
                              model, maps, **opts) for f in HALF_TURN_SCALES]
    product = np.array([h.score for h in candidates]) * weigh(candidates)
    chosen = candidates[int(np.argmax(product))]
    other = refine_viewpoint(chosen, model, maps, setup, weigh,
                             scale_bounds=_within_reach(chosen))
    other_weight = float(weigh([other])[0])
    if not other.score * other_weight > 0:
        return kept, False
    # The side that fits shrunk onto inner edges scores high in pixels; above
    # chance in object units each pose is judged at its own size.
    if sphere:
        # Among the sphere's close views a detail that sets the sides apart lies within a
        # cell of its template's: pooled gradients count it where grey levels blur it.
        found_like, other_like = resemble(found), resemble(other)
    else:
        found_like = float(weigh([found])[0])
        other_like = other_weight
    found_value = unit_score(found, model, features, shape, setup) * found_like
    other_value = unit_score(other, model, features, shape, setup) * other_like
    if not other_value > 0:
        return kept, False
    found_feats = pose_features(found, model, setup)
    other_feats = pose_features(other, model, setup)
    # The edges inside either outline: the object's, wherever either pose puts it.
    selected = (inside_pose(found, model, maps.xy, setup, found_feats)
                | inside_pose(other, model, maps.xy, setup, other_feats))
    share = edge_share(found, model, maps, selected, setup, features=found_feats)
    # A share is at most 1: the half-turn cannot win unless its value beats this.
    if other_value <= found_value * share:
        return kept, False
    if other_value * edge_share(other, model, maps, selected, setup,
                                features=other_feats) > found_value * share:
        return replace(other, score=float(other.score * other_weight), refined=True), True
    return kept, False
