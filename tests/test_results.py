"""Result types: frozen hypotheses in radians with degree properties, JSON-ready estimates."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from posevote.results import LOOKALIKE, Hypothesis, PoseEstimate


def _hyp(**kw):
    base = dict(azimuth=np.radians(30.0), elevation=0.0, inplane=np.radians(-5.0), scale=1.1,
                position=(10.0, 20.0), box=(0.0, 0.0, 21.0, 41.0), score=0.5, refined=True)
    return Hypothesis(**{**base, **kw})


def test_degrees_at_the_edges_and_frozen():
    h = _hyp()
    assert h.azimuth_deg == pytest.approx(30.0) and h.inplane_deg == pytest.approx(-5.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        h.score = 1.0  # type: ignore[misc]


def test_estimate_serialises_to_json():
    h = _hyp()
    est = PoseEstimate(found=True, best=h, modes=(h,), n_test_features=12, seconds=0.01)
    payload = json.loads(json.dumps(est.to_dict()))
    assert payload["found"] is True and len(payload["modes"]) == 1


def test_ambiguous_when_the_best_mode_is_more_likely_wrong():
    sure, coin = _hyp(probability=0.9), _hyp(probability=0.45)
    assert not PoseEstimate(found=True, best=sure, modes=(sure,)).ambiguous
    est = PoseEstimate(found=True, best=coin, modes=(coin, sure))
    assert est.ambiguous and est.to_dict()["ambiguous"] is True
    assert est.to_dict()["best"]["probability"] == 0.45
    # no probability computed: nothing says the estimate can be trusted
    assert PoseEstimate(found=True, best=_hyp(), modes=(_hyp(),)).ambiguous
    assert _hyp().to_dict()["probability"] is None
    assert not PoseEstimate(found=False, best=None).ambiguous
    # the profile the probabilities come from stays out of the JSON
    est = PoseEstimate(found=True, best=sure, modes=(sure,), viewpoint_scores=((0.0, 0.0, 1.0),))
    assert "viewpoint_scores" not in est.to_dict()


def test_ambiguous_when_the_object_looks_alike_from_another_side():
    ring, mug, old = (_hyp(probability=0.9, lookalike=LOOKALIKE + 0.05),
                      _hyp(probability=0.9, lookalike=LOOKALIKE - 0.05), _hyp(probability=0.9))
    assert PoseEstimate(found=True, best=ring, modes=(ring,)).ambiguous
    assert not PoseEstimate(found=True, best=mug, modes=(mug,)).ambiguous
    # not measured (a model file of an earlier posevote): the probability alone decides
    assert not PoseEstimate(found=True, best=old, modes=(old,)).ambiguous
    assert ring.to_dict()["lookalike"] == pytest.approx(LOOKALIKE + 0.05)
    assert "lookalike" not in old.to_dict()
