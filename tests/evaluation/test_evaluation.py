import numpy as np
import pytest

from posevote.evaluation import box_iou, paste_on_clutter, summarize_errors
from posevote.evaluation.plots import draw_overlay, plot_weights, write_png


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


def test_paste_on_clutter_truth(draw):
    img = draw(0.3)
    from posevote.data import object_box

    box = object_box(img)
    rng = np.random.default_rng(1)
    p = paste_on_clutter(img, box, rng=rng, occlusion=0.2)
    assert p.image.shape == (256, 256)
    assert 0.1 < p.occluded_fraction < 0.35
    assert 0.7 <= p.scale <= 1.3
    u, v = p.position
    x, y, w, h = p.box
    assert x <= u <= x + w and y <= v <= y + h


def test_clutter_search_covers_the_pasting_ranges():
    import inspect

    from posevote import PoseEstimator
    from posevote.evaluation.synthetic import CLUTTER_SEARCH

    defaults = inspect.signature(paste_on_clutter).parameters
    assert CLUTTER_SEARCH["scale_range"] == defaults["scale_range"].default
    assert CLUTTER_SEARCH["inplane_range_deg"] == defaults["inplane_range_deg"].default
    params = PoseEstimator(**CLUTTER_SEARCH).get_params()  # every key is a setting
    assert params["inplane_step_deg"] == CLUTTER_SEARCH["inplane_step_deg"]


def test_same_seed_same_image(draw):
    img = draw(0.3)
    box = np.array([30.0, 30.0, 60.0, 60.0])
    a = paste_on_clutter(img, box, rng=np.random.default_rng(5))
    b = paste_on_clutter(img, box, rng=np.random.default_rng(5))
    assert np.array_equal(a.image, b.image)


def test_plots_are_written(fitted_estimator, draw, tmp_path):
    plot_weights(fitted_estimator.model_, tmp_path / "w.png", n_views=3)
    assert (tmp_path / "w.png").stat().st_size > 1000
    result = fitted_estimator.estimate(draw(1.0))
    overlay = draw_overlay(draw(1.0), result, truth_box=(10, 10, 50, 50))
    assert overlay.ndim == 3 and overlay.shape[0] >= 256
    write_png(tmp_path / "o.png", overlay)
    assert (tmp_path / "o.png").stat().st_size > 1000
    assert not list(tmp_path.glob(".*"))  # no temporary files left
