"""Error summaries and box overlap."""

import numpy as np
import pytest

from posevote.evaluation import box_iou, summarize_errors


def test_summarize_errors():
    s = summarize_errors([1.0, 2.0, 3.0, 50.0])
    assert s["median"] == 2.5 and s["mean"] == 14.0 and s["under_45"] == 75.0 and s["n"] == 4
    with pytest.raises(ValueError, match="empty"):
        summarize_errors([])
    with pytest.raises(ValueError, match="NaN"):
        summarize_errors([1.0, np.nan])


def test_box_iou():
    assert box_iou([0, 0, 10, 10], [0, 0, 10, 10]) == pytest.approx(1.0)
    assert box_iou([0, 0, 10, 10], [5, 0, 10, 10]) == pytest.approx(50 / 150)
    assert box_iou([0, 0, 10, 10], [20, 20, 5, 5]) == 0.0
