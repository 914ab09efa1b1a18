import pytest


def test_demo_settings_are_validated_before_anything_is_written(tmp_path):
    pytest.importorskip("pybullet")
    from posevote.demo import DEMO_PRESET, run_demo

    assert DEMO_PRESET == "cluttered"
    with pytest.raises(ValueError, match="SearchOptions.scale_steps must be an integer"):
        run_demo(tmp_path / "out", n_test=1, overrides={"search__scale_steps": 0})
    assert not (tmp_path / "out").exists()


def test_demo_summary(tmp_path):
    pytest.importorskip("pybullet")
    from posevote.demo import run_demo

    summary = run_demo(tmp_path, n_test=2, seed=1, overrides={"search__scale_steps": 3})
    assert summary["n"] == 2
    assert 0.0 <= summary["position_within_5px"] <= 100.0
    assert (tmp_path / "results.csv").read_text().count("\n") == 3


def test_render_turntable_frames_any_mesh():
    pytest.importorskip("pybullet")
    import numpy as np

    from posevote.demo import render_turntable

    views = render_turntable(np.radians([0.0, 90.0, 200.0]), size=64, mesh="racecar/racecar.urdf",
                             base_euler=(0.0, 0.0, 0.0), distance=None)
    for view in views:
        assert view.mask.any()
        x, y, w, h = view.box
        assert x > 0 and y > 0 and x + w < 64 and y + h < 64  # whole object in view
        assert abs(x + w / 2 - 32) < 8  # turns about its own centre
    assert not np.array_equal(views[0].mask, views[1].mask)


def test_render_turntable_says_when_the_object_is_out_of_view():
    pytest.importorskip("pybullet")
    import numpy as np

    from posevote.demo import render_turntable

    with pytest.raises(ValueError, match="duck_vhacd.urdf: the object is not in view"):
        render_turntable(np.radians([0.0]), size=32, target=(5.0, 5.0, 5.0))
