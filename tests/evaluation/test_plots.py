"""The weights figure and the estimate overlay."""

from posevote.evaluation.plots import draw_overlay, plot_weights, write_png


def test_plots_are_written(fitted_estimator, draw, tmp_path):
    plot_weights(fitted_estimator.model_, tmp_path / "w.png", n_views=3)
    assert (tmp_path / "w.png").stat().st_size > 1000
    result = fitted_estimator.estimate(draw(1.0))
    overlay = draw_overlay(draw(1.0), result, truth_box=(10, 10, 50, 50))
    assert overlay.ndim == 3 and overlay.shape[0] >= 256
    write_png(tmp_path / "o.png", overlay)
    assert (tmp_path / "o.png").stat().st_size > 1000
    assert not list(tmp_path.glob(".*"))  # no temporary files left
