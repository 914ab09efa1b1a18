import functools
import json

import numpy as np
import pytest
from click.testing import CliRunner

from posevote import PoseEstimator
from posevote.cli import cli
from posevote.evaluation import sphere
from posevote.evaluation.sphere import SphereSetup, run_sphere, summarize
from posevote.evaluation.synthetic import PastedView
from posevote.geometry import box_centre

pytest.importorskip("pybullet")

# Two training elevations, views on black: the protocol end to end in seconds.
_SMALL = {"elevations_deg": (0.0, 30.0), "clean": True}


def test_setup_refuses_what_it_cannot_run():
    for bad in ({"mesh": "teapot.urdf"}, {"n_images": 0}, {"elevations_deg": (float("nan"),)},
                {"elevations_deg": ()}, {"seed": -1}, {"azimuth_step_deg": 7},
                {"azimuth_step_deg": 0}, {"texture": "no-such-image.png"}):
        with pytest.raises(ValueError, match=next(iter(bad)).split("_")[0]):
            SphereSetup(**bad)


def test_run_writes_the_report_and_is_reproducible(tmp_path):
    setup = SphereSetup(n_images=2, **_SMALL)
    seen = []
    summary = run_sphere(setup, tmp_path / "a", progress=lambda d, t: seen.append((d, t)))
    assert seen[-1] == (2, 2) and summary["n"] == 2 and summary["n_training_views"] == \
        2 * 360 // sphere.AZIMUTH_STEP_DEG
    for name in ("model.npz", "records.jsonl", "summary.json", "report.md",
                 "rotation_errors.png"):
        assert (tmp_path / "a" / name).stat().st_size > 0
    records = [json.loads(line) for line in
               (tmp_path / "a" / "records.jsonl").read_text().splitlines()]
    assert [r["seed"] for r in records] == setup.seeds()
    assert all(0 <= r["rotation_deg"] <= 180 and r["translation_pct"] >= 0 for r in records)
    report = (tmp_path / "a" / "report.md").read_text()
    assert "rotation median" in report
    assert "Steps: search → modes → fit → rescale [one instance]" in report   # on black
    # t_cam_obj names the mesh origin, learnt in each training view with its depth factor:
    # on black within 4% of its depth (the box centre's point lies 4-9% off in these two).
    origins = PoseEstimator.load(tmp_path / "a" / "model.npz").model_.view_origin
    assert origins is not None and origins.shape == (summary["n_training_views"], 3)
    assert all(r["translation_pct"] < 4.0 for r in records)
    run_sphere(setup, tmp_path / "b")
    again = [json.loads(line) for line in
             (tmp_path / "b" / "records.jsonl").read_text().splitlines()]
    drop = ("seconds",)
    assert [{k: v for k, v in r.items() if k not in drop} for r in records] == \
        [{k: v for k, v in r.items() if k not in drop} for r in again]


def test_a_coarser_grid_of_a_textured_mesh(tmp_path):
    setup = SphereSetup(mesh="duck_vhacd.urdf", texture="uvmap.png", azimuth_step_deg=90,
                        n_images=1, **_SMALL)
    summary = run_sphere(setup, tmp_path)
    assert summary["n_training_views"] == 2 * 4 and summary["texture"] == "uvmap.png"
    report = (tmp_path / "report.md").read_text()
    assert "duck_vhacd.urdf + uvmap.png" in report and "azimuth every 90 deg" in report
    record = json.loads((tmp_path / "records.jsonl").read_text())
    assert 0 <= record["elevation_error_deg"] <= 30


def test_the_models_in_clutter_are_morphed_over_the_sphere():
    # In clutter each view moves toward its neighbours along its ring and its column;
    # on black (the default preset) the views are not morphed.
    cluttered = sphere.train(SphereSetup(elevations_deg=(0.0, 30.0)))
    n = 2 * 360 // sphere.AZIMUTH_STEP_DEG
    assert cluttered.morph_views and cluttered.model_.view_neighbour.shape == (n, 4)
    assert (cluttered.model_.view_neighbour[:, :2] >= 0).all()
    assert cluttered.model_.shift.shape == (cluttered.model_.n_features, 4, 2)
    assert sphere.train(SphereSetup(**_SMALL)).model_.shift is None


def test_the_true_translation_is_the_mesh_origin():
    view = sphere._render(np.array([0.6]), 20.0, SphereSetup())[0]
    camera = sphere.render_camera()
    as_rendered = PastedView(image=view.image, position=box_centre(view.box), scale=1.0,
                             inplane=0.0, box=tuple(view.box), occluded_fraction=0.0)
    np.testing.assert_allclose(sphere.true_translation(view, as_rendered, camera), view.origin,
                               atol=1e-12)
    # Pasted half as large with its box centre 10 px to the right: twice as far, its
    # image half as far from the box centre.
    centre = np.asarray(box_centre(view.box))
    moved = PastedView(image=view.image, position=tuple(centre + (10, 0)), scale=0.5,
                       inplane=0.0, box=tuple(view.box), occluded_fraction=0.0)
    u, v = centre + (10, 0) + 0.5 * (camera.project(view.origin) - centre)
    np.testing.assert_allclose(sphere.true_translation(view, moved, camera),
                               camera.ray_point(u, v, 2 * view.origin[2]), atol=1e-12)


def test_summary_counts_a_missed_image_as_180_degrees_and_no_translation():
    recs = [{"rotation_deg": 5.0, "translation_pct": 1.0, "detected": True, "seconds": 1.0,
             "elevation_error_deg": 2.0},
            {"rotation_deg": 180.0, "translation_pct": None, "detected": False, "seconds": 3.0,
             "elevation_error_deg": None}]
    s = summarize(recs)
    assert s["elevation_median_deg"] == pytest.approx(46.0)     # a miss counts 90
    assert s["rotation_under_10_pct"] == 50.0 and s["translation_under_2_pct"] == 50.0
    assert s["rotation_mean_deg"] == pytest.approx(92.5) and s["detected_pct"] == 50.0
    assert s["flip_rate_pct"] == 50.0


def test_cli_evaluates_the_rendered_sphere(tmp_path, monkeypatch):
    monkeypatch.setattr(sphere, "SphereSetup", functools.partial(SphereSetup, **_SMALL))
    out = tmp_path / "sphere"
    result = CliRunner().invoke(cli, ["evaluate", "rendered-sphere", "--images", "1", "--out",
                                      str(out)])
    assert result.exit_code == 0, result.output
    assert "rotation median" in result.output and (out / "summary.json").exists()
    result = CliRunner().invoke(cli, ["evaluate", "rendered-sphere", "--data", str(tmp_path)])
    assert result.exit_code == 2 and "--data" in result.output
    result = CliRunner().invoke(cli, ["evaluate", "epfl-cv", "--out", str(tmp_path / "e")])
    assert result.exit_code == 2 and "needs the data folder" in result.output


def test_known_depths_search_the_scales_of_the_test_depths(tmp_path, monkeypatch):
    from posevote import PoseEstimator

    seen = []
    estimate = PoseEstimator.estimate
    monkeypatch.setattr(PoseEstimator, "estimate",
                        lambda self, *a, **k: seen.append(self.search) or estimate(self, *a, **k))
    run_sphere(SphereSetup(n_images=1, known_depths=True, **_SMALL), tmp_path)
    low, high = seen[-1].scale_range
    # The model's height is learnt from the training distances: about the pasted scales.
    assert low == pytest.approx(sphere.SCALE_RANGE[0], rel=0.05)
    assert high == pytest.approx(sphere.SCALE_RANGE[1], rel=0.05)
    assert "the test depths known" in (tmp_path / "report.md").read_text()
