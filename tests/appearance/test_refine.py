"""Appearance refinement: the verified box is kept, the viewpoint is the nearest view's, and
the box tells its side from the half-turned one."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from posevote import PoseEstimator
from posevote.appearance import AppearanceOptions
from posevote.appearance.refine import appearance_refine, front_back_share
from posevote.geometry import box_iou


@pytest.fixture(scope="module")
def refined_setup(synthetic_training, draw):
    images, az, boxes = synthetic_training
    est = PoseEstimator(appearance=AppearanceOptions(candidates=0, jitter=0.0))
    est.fit(images, az, boxes=boxes)
    img = draw(np.radians(110.0))
    return est, img, est.estimate(img).best


def test_the_viewpoint_becomes_a_training_view_near_the_estimate(refined_setup):
    from posevote.data import object_box

    est, img, best = refined_setup
    assert np.min(np.abs(np.degrees(best.azimuth) - np.array([100.0, 120.0]))) < 1e-6
    assert box_iou(best.box, object_box(img)) > 0.7


def test_a_verified_box_is_kept_as_it_is(refined_setup):
    est, img, best = refined_setup
    box = (best.box[0] + 3.0, best.box[1] - 2.0, best.box[2], best.box[3])
    kept = appearance_refine(replace(best, box=box), img, est.model_, est.appearance_model_,
                             est.appearance, verified_box=box)
    assert kept.box == box
    assert kept.position == pytest.approx((box[0] + (box[2] - 1) / 2, box[1] + (box[3] - 1) / 2))


def test_without_a_box_regression_it_says_to_retrain(refined_setup):
    est, img, best = refined_setup
    look = replace(est.appearance_model_, regressor=None)
    with pytest.raises(ValueError, match="retrain"):
        appearance_refine(best, img, est.model_, look, est.appearance)


def test_the_box_looks_like_its_own_side_more_than_the_half_turned_one(refined_setup):
    est, img, best = refined_setup
    grey = np.asarray(img, dtype=np.float32)
    share = front_back_share(best, grey, est.model_, est.appearance_model_)
    turned = front_back_share(replace(best, azimuth=best.azimuth + np.pi), grey, est.model_,
                              est.appearance_model_)
    assert share is not None and turned is not None
    assert share > 0.5 > turned and share + turned == pytest.approx(1.0)
    # A box off the image cannot be described.
    away = replace(best, box=(-500.0, -500.0, 10.0, 10.0))
    assert front_back_share(away, grey, est.model_, est.appearance_model_) is None


def test_the_estimate_reports_the_front_back_share_as_its_probability(refined_setup):
    est, img, best = refined_setup
    assert est.search.calibration == (1.0, 0.0, 0.0)   # the share itself
    grey = np.asarray(img, dtype=np.float32)
    assert best.probability == pytest.approx(
        front_back_share(best, grey, est.model_, est.appearance_model_))
