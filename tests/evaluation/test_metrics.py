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


def test_calibration_bins_and_error():
    from posevote.evaluation.metrics import calibration

    cal = calibration([0.95, 0.95, 0.15, 0.15], [True, False, False, False])
    assert cal["n"] == 4 and cal["ece"] == pytest.approx(0.5 * 0.45 + 0.5 * 0.15)
    assert [b[2] for b in cal["bins"]] == [0, 2, 0, 0, 0, 0, 0, 0, 0, 2]
    assert calibration([1.0], [True])["ece"] == 0.0          # 1.0 falls in the last bin
    with pytest.raises(ValueError, match="outcomes"):
        calibration([0.5], [True, False])


def test_risk_coverage_and_precision():
    from posevote.evaluation.metrics import (
        accuracy_at_coverage,
        average_precision,
        risk_coverage,
    )

    cov, acc = risk_coverage([0.9, 0.1, 0.5, 0.7], [True, False, False, True])
    assert cov.tolist() == [0.25, 0.5, 0.75, 1.0] and acc.tolist() == [1.0, 1.0, 2 / 3, 0.5]
    assert accuracy_at_coverage([0.9, 0.1, 0.5, 0.7], [True, False, False, True], 0.5) == 1.0
    assert average_precision([0.9, 0.8], [True, True], 2) == 1.0
    assert average_precision([0.9, 0.8], [False, True], 4) == pytest.approx(0.125)
