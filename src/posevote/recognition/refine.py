"""Refinement with an instance model (Sec. III-B): recognise the instance, re-estimate with it.

A category model pools the views of several instances; its estimate is
blurred by their differences. Each instance is scored at the category's
estimate (Eqs. 5-6, :func:`posevote.recognition.score.explained_fraction`)
and, when one wins by ``margin``, the pose is estimated again near the
category's mode with that instance's own (full, unpruned) model. With
``search`` (beyond the paper), each instance's model first estimates the pose
on its own, over every viewpoint and on the scale grid centred on the
instance's training size, and the instances are scored at their own
estimates: a near search cannot undo the category's front/back confusions,
and a grid centred on the median instance misses the small and large ones.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from posevote.features.edges import EdgeFeatures
from posevote.geometry import angular_error
from posevote.inference.search import probe
from posevote.inference.setup import SearchSetup
from posevote.model.density import PoseModel
from posevote.model.kernels import ORIENTATION_KAPPA
from posevote.recognition import RecognitionOptions
from posevote.recognition.score import explained_fraction, recognition_margin
from posevote.refinement.fitting import FIT_RADIUS_STEPS, refine_mode
from posevote.refinement.local import local_refine, polish_pose
from posevote.results import Hypothesis
from posevote.scoring.maps import TestMaps
from posevote.scoring.score import pose_score, score_options

#: Without ``search``, instances are scored at this many of the best category
#: modes (a front/back confusion of the category can be an instance's right
#: pose); the instance is refined at the mode where it scored best.
RECOGNITION_MODES = 2

#: Each instance is aligned on about this many of its view's features (an
#: even stride): the alignment only places the instance for the judgement
#: (docs/DEFAULTS.md).
ALIGN_FEATURES = 300

#: Only this many instances, those whose exact score at their hypothesis (on
#: ALIGN_FEATURES features, before the alignment) is highest, are aligned
#: and judged; the others explain nothing: as good a choice as all of them,
#: in less time (docs/DEFAULTS.md).
RECOGNITION_SHORTLIST = 4


def explained(hypotheses: Sequence[Hypothesis], features: EdgeFeatures, full: PoseModel,
              maps: TestMaps, setup: SearchSetup) -> NDArray[np.float64]:
    """Each instance's explained fraction (Eqs. 5-6), aligned from its own hypothesis.

    Each instance's own model is first aligned to the image from its
    hypothesis (in-plane angle, scale and translation polished on the exact
    p(w) of :data:`ALIGN_FEATURES` of its features, since instances differ
    in shape); all instances are then judged on
    the same test features, those in the union of their boxes. Of more than
    :data:`RECOGNITION_SHORTLIST` instances, only those that score best
    before the alignment are aligned and judged; the others get 0.

    Parameters
    ----------
    hypotheses : sequence of Hypothesis
        One per instance of ``full``.
    features : EdgeFeatures
        The test image's features.
    full : PoseModel
        The full (unpruned) model of all instances.
    maps : TestMaps
        The test image tabulated with the narrow kernel.
    setup : SearchSetup

    Returns
    -------
    ndarray, shape (n_instances,)
        0 for the instances left off the shortlist.
    """
    kw = score_options(setup)
    subs = [full.instance_model(i) for i in range(len(full.instance_names))]
    judged = np.arange(len(subs))
    if len(subs) > RECOGNITION_SHORTLIST:
        start = [pose_score(h, sub, maps, max_features=ALIGN_FEATURES, **kw)
                 for h, sub in zip(hypotheses, subs, strict=True)]
        judged = np.sort(np.argsort(-np.array(start), kind="stable")[:RECOGNITION_SHORTLIST])
    aligned = [polish_pose(hypotheses[int(i)], subs[i], maps, max_features=ALIGN_FEATURES, **kw)
               for i in judged]
    corners = np.array([[h.box[0], h.box[1], h.box[0] + h.box[2], h.box[1] + h.box[3]]
                        for h in aligned])
    lo, hi = corners[:, :2].min(axis=0), corners[:, 2:].max(axis=0)
    box = (float(lo[0]), float(lo[1]), float(hi[0] - lo[0]), float(hi[1] - lo[1]))
    fractions = np.zeros(len(subs))
    fractions[judged] = [
        explained_fraction(features, subs[i], h, box=box, position_sigma=setup.position_sigma,
                           orientation_kappa=ORIENTATION_KAPPA, **kw)
        for i, h in zip(judged, aligned, strict=True)]
    return fractions


def instance_refine(instance: int, hypothesis: Hypothesis, full: PoseModel,
                    search_maps: TestMaps | Sequence[TestMaps | None], fine: TestMaps,
                    setup: SearchSetup, *, fit: bool, local: str | None, near: bool = True
                    ) -> Hypothesis:
    """Re-estimate near ``hypothesis`` with one instance's full model (Sec. III-B).

    With ``near=False`` the instance searches every viewpoint, on the scale
    grid centred on its training size (``RecognitionOptions.search``). Its
    best mode is refined as the estimate refines its own: fitted with
    ``fit``, refined locally with ``local`` (``"polish"`` or ``"profile"``,
    :func:`posevote.refinement.local.local_refine`).
    """
    model = full.instance_model(instance)
    probes = probe(model, search_maps, setup, near=hypothesis) if near else \
        probe(model, search_maps, setup, size=full.size_of(instance))
    if not probes.score.any():
        return hypothesis
    v = int(np.argmax(probes.score.max(axis=(1, 2))))
    refined = refine_mode(probes, v, fit=fit, radius_steps=FIT_RADIUS_STEPS)
    if local is not None:
        refined = local_refine(probes, v, refined, model, setup, profile=local == "profile",
                               narrow=lambda: fine, scale_step=setup.options.scale_step())
    return refined


def recognize(hypotheses: list[Hypothesis], features: EdgeFeatures, full: PoseModel,
              search_maps: TestMaps | Sequence[TestMaps | None], fine: TestMaps,
              setup: SearchSetup, options: RecognitionOptions, *, fit: bool, local: str | None
              ) -> tuple[list[Hypothesis], str, float]:
    """Recognise the instance and re-estimate with its model (Sec. III-B).

    Parameters
    ----------
    hypotheses : list of Hypothesis
        The category's modes, best first.
    features : EdgeFeatures
        The test features (inside the verified box, if any).
    full : PoseModel
        The full model of all instances.
    search_maps : TestMaps or list of TestMaps
        The search's maps.
    fine : TestMaps
        The narrow maps.
    setup : SearchSetup
    options : RecognitionOptions
    fit : bool
        Fit the instance's estimate (:attr:`~posevote.refinement.RefineOptions.fit`).
    local : {None, "polish", "profile"}
        Refine it locally (:attr:`~posevote.refinement.RefineOptions.local`).

    Returns
    -------
    modes : list of Hypothesis
        The instance's estimate first when one wins by ``options.margin``.
    instance : str
        Its name ("" if none won).
    margin : float
        The recognition margin.
    """
    names = full.instance_names
    if options.search:
        own = [instance_refine(i, hypotheses[0], full, search_maps, fine, setup,
                               fit=fit, local=local, near=False)
               for i in range(len(names))]
        best, margin = recognition_margin(explained(own, features, full, fine, setup))
        if margin < options.margin:
            return hypotheses, "", margin
        # The category mode nearest to the instance's estimate gives way to it.
        at = int(np.argmin([angular_error(h.azimuth, own[best].azimuth) for h in hypotheses]))
        refined = own[best]
    else:
        per_mode = np.array([explained([h] * len(names), features, full, fine, setup)
                             for h in hypotheses[:RECOGNITION_MODES]])
        best, margin = recognition_margin(per_mode.max(axis=0))
        if margin < options.margin:
            return hypotheses, "", margin
        at = int(np.argmax(per_mode[:, best]))
        refined = instance_refine(best, hypotheses[at], full, search_maps, fine, setup,
                                  fit=fit, local=local)
    return [refined] + [h for k, h in enumerate(hypotheses) if k != at], names[best], margin
