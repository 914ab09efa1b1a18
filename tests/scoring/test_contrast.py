"""The contrast step: a mode's score against what its pose scores elsewhere in its frame."""

import math

import cv2
import numpy as np
import pytest

from posevote import PoseEstimator
from posevote.data import toy_views
from posevote.geometry import box_iou
from posevote.results import Hypothesis
from posevote.scoring.contrast import (
    MAX_OVERLAP,
    MIN_PLACEMENTS,
    SPREAD_FLOOR,
    background_scores,
    mode_contrast,
    placements,
)


def _mode(position, box, score=0.5):
    return Hypothesis(azimuth=0.0, elevation=0.0, inplane=0.0, scale=1.0, position=position,
                      box=box, score=score, refined=True)


def test_placements_keep_off_the_modes_box():
    mode = _mode((300.0, 200.0), (260.0, 170.0, 80.0, 60.0))
    u, v = placements(mode, (480, 640))
    assert len(u) > 100
    ious = [box_iou((260.0 + du - 300.0, 170.0 + dv - 200.0, 80.0, 60.0), mode.box)
            for du, dv in zip(u, v, strict=True)]
    assert max(ious) <= MAX_OVERLAP
    # A box filling its crop: the least overlapping placements, never fewer than the minimum.
    full = _mode((60.0, 60.0), (4.0, 4.0, 112.0, 112.0))
    u, v = placements(full, (120, 120))
    assert len(u) == MIN_PLACEMENTS
    assert min(abs(u - 60.0) + abs(v - 60.0)) > 0


@pytest.fixture(scope="module")
def toy_estimator():
    images, poses, boxes = toy_views(range(0, 360, 30))
    return PoseEstimator(min_score=0.0).fit(images, poses, boxes=boxes)


def _frame(view, clutter):
    canvas = np.zeros((480, 640))
    canvas[100:228, 200:328] = view
    if clutter:
        # Other views of the object strewn over the frame: background that scores.
        rng = np.random.default_rng(0)
        others = toy_views(range(15, 360, 45))[0]
        for k, other in enumerate(others):
            y, x = [(10, 10), (300, 20), (320, 450), (20, 480), (300, 250), (200, 20),
                    (180, 470), (340, 120)][k]
            turned = cv2.warpAffine(other, cv2.getRotationMatrix2D((64, 64), rng.uniform(
                60, 120), 1.0), (128, 128))
            canvas[y:y + 128, x:x + 128] = np.maximum(canvas[y:y + 128, x:x + 128], turned)
    return canvas


def test_contrast_is_measured_and_read_by_the_threshold(toy_estimator):
    view = toy_views([60])[0][0]
    est = toy_estimator.set_params(search__contrast=False)
    plain = est.estimate(_frame(view, clutter=False))
    assert math.isnan(plain.best.contrast)
    assert plain.best.detection_score == plain.best.score == plain.top_score
    assert "contrast" not in plain.best.to_dict()
    est.set_params(search__contrast=True)
    try:
        bare = est.estimate(_frame(view, clutter=False))
        busy = est.estimate(_frame(view, clutter=True))
        # The same pose: the frame's busier background makes it stand out less.
        assert abs(bare.best.azimuth_deg - busy.best.azimuth_deg) < 10
        assert bare.best.contrast > busy.best.contrast > 0
        assert bare.top_score == max(m.contrast for m in bare.modes)
        assert bare.best.to_dict()["contrast"] == bare.best.contrast
        # min_score reads the contrast: a threshold over the score, under the contrast.
        est.set_params(min_score=busy.best.score * 2)
        assert est.estimate(_frame(view, clutter=True)).found
        est.set_params(min_score=busy.best.contrast * 1.01)
        assert not est.estimate(_frame(view, clutter=True)).found
    finally:
        est.set_params(search__contrast=False, min_score=0.0)


def _cluttered_mode(est):
    """The best mode in a cluttered frame, the state before the steps, the score options."""
    from posevote import pipeline
    from posevote.scoring.score import score_options

    est.set_params(search__contrast=False)
    image = _frame(toy_views([60])[0][0], clutter=True)
    best = est.estimate(image).best
    settings = est._settings()
    state = pipeline.begin(settings, est._trained(), image,
                           pipeline.extract_edges(image, est.edges, training=False),
                           steps=pipeline.active_steps(settings))
    return best, state, score_options(state.setup)


def test_background_scores_read_the_frame_away_from_the_mode(toy_estimator):
    est = toy_estimator
    best, state, options = _cluttered_mode(est)
    scores = background_scores(best, est._trained().model, state.narrow(), state.shape,
                               **options)
    assert len(scores) == len(placements(best, state.shape)[0])
    assert scores.max() > 0 and scores.min() >= 0
    # None of them is the object itself.
    assert scores.max() < best.score
    z = best.score / (scores.std() + SPREAD_FLOOR)
    places = state.shape[0] * state.shape[1] / (best.box[2] * best.box[3])
    assert mode_contrast(best, est._trained().model, state.narrow(), state.shape,
                         **options) == pytest.approx(math.sqrt(z * z - 2.0 * math.log(places)))


def test_the_contrast_asks_more_of_a_box_with_more_places_in_its_frame(toy_estimator):
    from dataclasses import replace

    est = toy_estimator
    best, state, options = _cluttered_mode(est)

    def contrast(mode, shape):
        return mode_contrast(mode, est._trained().model, state.narrow(), shape, **options)

    # The same pose and score, its box a quarter of the area: four times the places.
    x, y, w, h = best.box
    small = replace(best, box=(x, y, w / 2, h / 2))
    assert contrast(small, state.shape) < contrast(best, state.shape)
    # A box as large as its frame has one place: the contrast is the score over the spread.
    whole = replace(best, box=(0.0, 0.0, float(state.shape[1]), float(state.shape[0])))
    z = best.score / (background_scores(whole, est._trained().model, state.narrow(),
                                        state.shape, **options).std() + SPREAD_FLOOR)
    assert contrast(whole, state.shape) == pytest.approx(z)


def test_contrast_option_is_a_flag():
    from posevote.inference.setup import SearchOptions

    with pytest.raises(ValueError, match="contrast"):
        SearchOptions(contrast="yes")
    assert SearchOptions(contrast=True).contrast is True


def test_a_frame_without_edges_has_nothing_to_measure(toy_estimator):
    est = toy_estimator.set_params(search__contrast=True)
    try:
        blank = est.estimate(np.zeros((480, 640)))
        assert not blank.found and blank.top_score == 0.0
    finally:
        est.set_params(search__contrast=False)
