"""Refinement with an instance model (Sec. III-B): recognition and re-estimation."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from posevote import PoseEstimator
from posevote.features.edges import extract_edges
from posevote.inference.setup import search_maps
from posevote.recognition import RecognitionOptions
from posevote.recognition.refine import explained, recognize
from posevote.refinement.fitting import find_modes, refine_mode
from posevote.scoring.score import narrow_maps


def _marked(img):
    # A dark bar across the plate: the one difference between the instances.
    out = img.copy()
    cv2.rectangle(out, (68, 50), (76, 90), 0.1, -1, cv2.LINE_AA)
    return out


@pytest.fixture(scope="module")
def two_instances(synthetic_training, draw):
    from posevote.data import object_box

    images, az, boxes = synthetic_training
    marked = [_marked(im) for im in images]
    est = PoseEstimator(recognition=None).fit(
        images + marked, np.concatenate([az, az]),
        boxes=np.vstack([boxes, [object_box(im) for im in marked]]),
        instances=["a"] * 18 + ["b"] * 18)
    image = _marked(draw(np.radians(70.0)))
    feats = extract_edges(image, est.edges, training=False)
    setup = est.setup()
    maps = search_maps(feats, image.shape, est.model_, setup)
    probes = est.probe(image)[0]
    hyps = [refine_mode(probes, v) for v in find_modes(probes)]
    return est, feats, maps, narrow_maps(feats, image.shape, setup), setup, hyps


def test_the_marked_instance_explains_its_mark(two_instances):
    est, feats, _, fine, setup, hyps = two_instances
    scores = explained([hyps[0]] * 2, feats, est.full_model_, fine, setup)
    assert scores[1] > scores[0]


def test_recognition_names_the_winner_and_abstains_below_the_margin(two_instances):
    est, feats, maps, fine, setup, hyps = two_instances
    kw = dict(fit=True, local=None)
    modes, name, margin = recognize(hyps, feats, est.full_model_, maps, fine, setup,
                                    RecognitionOptions(margin=1.01, search=False), **kw)
    assert name == "b" and margin >= 1.01 and len(modes) == len(hyps)
    assert abs(np.degrees(modes[0].azimuth) - 70.0) < 10.0
    same, none, _ = recognize(hyps, feats, est.full_model_, maps, fine, setup,
                              RecognitionOptions(margin=50.0, search=False), **kw)
    assert none == "" and same == hyps


def test_only_the_shortlist_is_judged(two_instances, monkeypatch):
    import posevote.recognition.refine as instance
    from posevote.scoring.score import pose_score, score_options

    est, feats, _, fine, setup, hyps = two_instances
    full = explained([hyps[0]] * 2, feats, est.full_model_, fine, setup)
    monkeypatch.setattr(instance, "RECOGNITION_SHORTLIST", 1)
    short = explained([hyps[0]] * 2, feats, est.full_model_, fine, setup)
    start = [pose_score(hyps[0], est.full_model_.instance_model(i), fine,
                        max_features=instance.ALIGN_FEATURES, **score_options(setup))
             for i in range(2)]
    kept = int(np.argmax(start))
    assert start[kept] > 0 and short[1 - kept] == 0.0 and short[kept] > 0.0
    # Judged in its own box rather than the union of both: about the same fraction.
    assert short[kept] == pytest.approx(full[kept], rel=0.2)
