"""Error summaries and box overlap."""

import numpy as np
import pytest

from posevote.evaluation import box_iou, summarize_errors
from posevote.evaluation.metrics import flip_threshold_deg


def test_summarize_errors():
    s = summarize_errors([1.0, 2.0, 3.0, 50.0])
    assert s["median"] == 2.5 and s["mean"] == 14.0 and s["under_45"] == 75.0 and s["n"] == 4
    assert s["flip_rate"] == 0.0


def test_flip_rate_counts_half_turns_and_quarter_turns_on_the_half_circle():
    assert summarize_errors([1.0, 170.0, 140.0, 100.0])["flip_rate"] == 50.0
    assert flip_threshold_deg(False) == 135.0 and flip_threshold_deg(True) == 67.5
    # one value per error: a half-turn symmetric object's 80 degrees is a flip, a car's is not
    s = summarize_errors([80.0, 80.0], flip_deg=[flip_threshold_deg(True), flip_threshold_deg(False)])
    assert s["flip_rate"] == 50.0
    with pytest.raises(ValueError, match="empty"):
        summarize_errors([])
    with pytest.raises(ValueError, match="NaN"):
        summarize_errors([1.0, np.nan])


def test_box_iou():
    assert box_iou([0, 0, 10, 10], [0, 0, 10, 10]) == pytest.approx(1.0)
    assert box_iou([0, 0, 10, 10], [5, 0, 10, 10]) == pytest.approx(50 / 150)
    assert box_iou([0, 0, 10, 10], [20, 20, 5, 5]) == 0.0
