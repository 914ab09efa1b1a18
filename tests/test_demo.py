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
    import csv

    from posevote.demo import run_demo

    summary = run_demo(tmp_path, n_test=2, seed=1, overrides={"search__scale_steps": 3})
    assert summary["n"] == 2
    assert 0.0 <= summary["position_within_5px"] <= 100.0
    assert (tmp_path / "results.csv").read_text().count("\n") == 3
    # Every image is estimated; "found" is the preset's threshold on its detection score.
    rows = list(csv.DictReader((tmp_path / "results.csv").read_text().splitlines()))
    from posevote import PoseEstimator

    threshold = PoseEstimator.from_preset("cluttered").min_score
    assert summary["threshold"] == threshold
    assert [r["found"] == "True" for r in rows] == [float(r["detection_score"]) > threshold
                                                   for r in rows]
    assert all(r["azimuth_est_deg"] != "nan" for r in rows)
    assert summary["found"] == sum(r["found"] == "True" for r in rows)
    assert 0 <= summary["found_right"] <= summary["found"]


def test_demo_refuses_an_unknown_mesh(tmp_path):
    pytest.importorskip("pybullet")
    from posevote.demo import run_demo

    with pytest.raises(ValueError, match="mesh must be one of"):
        run_demo(tmp_path / "out", n_test=1, mesh="teapot.urdf")
    assert not (tmp_path / "out").exists()
