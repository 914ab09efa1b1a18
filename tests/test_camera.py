"""The camera: intrinsics, camera files, the object's height and its pose in the camera frame."""

from __future__ import annotations

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from posevote import PoseEstimator
from posevote.camera import (
    Camera,
    object_height_from_distances,
    origin_depth_factors,
    place,
    read_camera,
    scale_range_for_depths,
)
from posevote.cli import cli
from posevote.geometry import transform_from_pose
from posevote.results import Hypothesis

CAM = {"fx": 500.0, "fy": 520.0, "cx": 64.0, "cy": 60.0}


def test_camera_from_either_form_and_refused_values():
    a = Camera.from_dict(CAM)
    b = Camera.from_dict({"K": [[500, 0, 64], [0, 520, 60], [0, 0, 1]]})
    assert a == b and a.K[1, 1] == 520.0 and a.to_dict() == CAM
    for bad, text in [({**CAM, "fx": 0}, "Camera.fx must be a positive"),
                      ({**CAM, "cy": float("nan")}, "Camera.cy"),
                      ({"fx": 1, "fy": 1, "cx": 0}, "missing"),
                      ({**CAM, "fz": 1}, "unknown"),
                      ({"K": [[1, 0], [0, 1]]}, "K must be"),
                      ({"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "fx": 1}, "not both"),
                      ([1, 2], "expected an object")]:
        with pytest.raises(ValueError, match=text):
            Camera.from_dict(bad, where="cam.json")


def test_read_camera_names_the_file(tmp_path):
    (tmp_path / "c.json").write_text(json.dumps(CAM))
    assert read_camera(tmp_path / "c.json").fx == 500.0
    (tmp_path / "bad.json").write_text("{fx: 1")
    with pytest.raises(ValueError, match="bad.json: not a JSON camera file"):
        read_camera(tmp_path / "bad.json")
    (tmp_path / "neg.json").write_text(json.dumps({**CAM, "fy": -1}))
    with pytest.raises(ValueError, match="neg.json: Camera.fy"):
        read_camera(tmp_path / "neg.json")
    with pytest.raises(FileNotFoundError, match="camera file not found"):
        read_camera(tmp_path / "none.json")


@pytest.mark.parametrize(("text", "message"), [
    ('{"fx": 500, "fx": 600, "fy": 500, "cx": 1, "cy": 1}', "the key 'fx' appears twice"),
    ("[" * 100_000 + "]" * 100_000, "the JSON nests too deep"),
    ('{"fx": 500, "fy": 500, "cx": 1, "cy": 1, "width": "abc"}', "width must be a whole"),
    ('{"fx": 500, "fy": 500, "cx": 1, "cy": 1, "height": 0}', "height must be a whole"),
    ('{"fx": 1e-9, "fy": 500, "cx": 1, "cy": 1}', "Camera.fx must be a positive number"),
])
def test_camera_files_with_absurd_content_are_refused(tmp_path, text, message):
    (tmp_path / "cam.json").write_text(text)
    with pytest.raises(ValueError, match=f"cam.json: {message}"):
        read_camera(tmp_path / "cam.json")


def test_object_height_from_distances():
    cam = Camera.from_dict(CAM)
    # A 0.2 m object at 1, 2 and 4 m appears fy * 0.2 / d pixels high.
    d = np.array([1.0, 2.0, 4.0])
    assert object_height_from_distances(520.0 * 0.2 / d, d, cam) == pytest.approx(0.2)
    with pytest.raises(ValueError, match="one distance per training view"):
        object_height_from_distances([10.0, 20.0], [1.0], cam)
    with pytest.raises(ValueError, match="positive"):
        object_height_from_distances([10.0], [0.0], cam)


def test_project_and_ray_point_invert_each_other():
    cam = Camera.from_dict(CAM)
    point = np.array([0.3, -0.2, 2.5])
    u, v = cam.project(point)
    assert (u, v) == pytest.approx((500.0 * 0.3 / 2.5 + 64.0, 520.0 * -0.2 / 2.5 + 60.0))
    np.testing.assert_allclose(cam.ray_point(u, v, 2.5), point, atol=1e-12)


def test_origin_depth_factors_are_depths_over_the_models_depth():
    cam = Camera.from_dict(CAM)
    # At training size (100 px high) a 0.25 m object is placed at 520 * 0.25 / 100 m.
    at = 520.0 * 0.25 / 100.0
    factors = origin_depth_factors([at, 1.1 * at], cam, object_height_m=0.25,
                                   reference_size_px=100.0)
    np.testing.assert_allclose(factors, [1.0, 1.1])


def test_place_agrees_with_the_full_transform():
    cam = Camera.from_dict(CAM)
    hyp = Hypothesis(azimuth=0.7, elevation=0.2, inplane=-0.3, scale=0.8, position=(80.0, 50.0),
                     box=(60.0, 30.0, 40.0, 40.0), score=0.9, refined=True)
    placed = place(hyp, cam, reference_size_px=100.0, object_height_m=0.25)
    depth = cam.fy * 0.25 / (0.8 * 100.0)
    T = transform_from_pose(0.7, 0.2, -0.3, 0.8, 80.0, 50.0, K=cam.K,
                            reference_depth=depth * 0.8)
    np.testing.assert_allclose(np.array(placed.T_cam_obj), T, atol=1e-12)
    R = np.array(placed.R_cam_obj)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert placed.t_cam_obj[2] == pytest.approx(depth)
    d = placed.to_dict()
    assert len(d["R_cam_obj"]) == 3 and d["t_cam_obj_m"][2] == pytest.approx(depth)
    unplaced = place(hyp, cam, reference_size_px=100.0, object_height_m=None)
    assert unplaced.R_cam_obj is not None and unplaced.t_cam_obj is None
    assert unplaced.T_cam_obj is None and "t_cam_obj_m" not in unplaced.to_dict()
    assert "R_cam_obj" not in hyp.to_dict()


def test_scale_range_for_depths_inverts_place():
    cam = Camera.from_dict(CAM)
    low, high = scale_range_for_depths((0.5, 2.0), cam, object_height_m=0.25,
                                       reference_size_px=100.0)
    hyp = Hypothesis(azimuth=0.0, elevation=0.0, inplane=0.0, scale=1.0, position=(64.0, 60.0),
                     box=(44.0, 40.0, 40.0, 40.0), score=0.9, refined=True)
    # The largest scale is the nearest depth, the smallest the farthest.
    for scale, depth in ((high, 0.5), (low, 2.0)):
        placed = place(replace(hyp, scale=scale), cam, reference_size_px=100.0,
                       object_height_m=0.25)
        assert placed.t_cam_obj[2] == pytest.approx(depth)
    for bad, match in (((2.0, 0.5), "nearest < farthest"), ((0.0, 1.0), "nearest < farthest"),
                       ((float("nan"), 1.0), "nearest < farthest"), ((1.0,), "two numbers"),
                       ("near", "two numbers")):
        with pytest.raises(ValueError, match=match):
            scale_range_for_depths(bad, cam, object_height_m=0.25, reference_size_px=100.0)
    with pytest.raises(ValueError, match="needs the object's height"):
        scale_range_for_depths((0.5, 2.0), cam, object_height_m=None, reference_size_px=100.0)


def test_estimate_with_a_camera(synthetic_training, draw, tmp_path):
    images, az, boxes = synthetic_training
    est = PoseEstimator().fit(images, az, boxes=boxes, object_height_m=0.3)
    cam = Camera.from_dict(CAM)
    plain = est.estimate(draw(np.radians(100)))
    placed = est.estimate(draw(np.radians(100)), camera=cam)
    assert plain.best.R_cam_obj is None
    assert placed.best.azimuth == plain.best.azimuth
    depth = cam.fy * 0.3 / (placed.best.scale * est.model_.reference_size)
    assert placed.best.t_cam_obj[2] == pytest.approx(depth)
    est.save(tmp_path / "m.npz")
    assert PoseEstimator.load(tmp_path / "m.npz").object_height_m_ == 0.3
    with pytest.raises(TypeError, match="posevote.camera.Camera"):
        est.estimate(draw(np.radians(100)), camera=CAM)
    with pytest.raises(ValueError, match="object_height_m must be a positive"):
        PoseEstimator().fit(images, az, object_height_m=-1.0)


@pytest.fixture()
def metric_folder(tmp_path, synthetic_training):
    images, az, boxes = synthetic_training
    lines = ["image,azimuth_deg,box_x,box_y,box_w,box_h,distance_m"]
    for i, (img, a, b) in enumerate(zip(images, az, boxes, strict=True)):
        cv2.imwrite(str(tmp_path / f"v{i:02d}.png"), (img * 255).astype(np.uint8))
        lines.append(f"v{i:02d}.png,{np.degrees(a):.1f},{b[0]},{b[1]},{b[2]},{b[3]},1.5")
    (tmp_path / "poses.csv").write_text("\n".join(lines) + "\n")
    (tmp_path / "cam.json").write_text(json.dumps(CAM))
    return tmp_path


def test_cli_train_and_estimate_in_metres(metric_folder, synthetic_training, draw):
    _, _, boxes = synthetic_training
    runner = CliRunner()
    model = metric_folder / "m.npz"
    r = runner.invoke(cli, ["train", str(metric_folder), "--camera", str(metric_folder / "cam.json"),
                            "-o", str(model)])
    assert r.exit_code == 0, r.output
    expected = np.median(boxes[:, 3] * 1.5 / CAM["fy"])
    assert PoseEstimator.load(model).object_height_m_ == pytest.approx(expected)
    test = metric_folder / "test.png"
    cv2.imwrite(str(test), (draw(np.radians(100)) * 255).astype(np.uint8))
    r = runner.invoke(cli, ["estimate", str(model), str(test), "--json", "--camera",
                            str(metric_folder / "cam.json")])
    assert r.exit_code == 0, r.output
    best = json.loads(r.output)["best"]
    # The test object is drawn as in training: about the training distance.
    assert best["t_cam_obj_m"][2] == pytest.approx(1.5, rel=0.15)
    assert np.array(best["T_cam_obj"]).shape == (4, 4)
    r = runner.invoke(cli, ["estimate", str(model), str(test), "--camera",
                            str(metric_folder / "cam.json")])
    assert "R_cam_obj [" in r.output and "t_cam_obj [" in r.output


def test_cli_depth_range_sets_the_scales_searched(metric_folder, draw, monkeypatch):
    runner = CliRunner()
    model, cam = metric_folder / "m.npz", str(metric_folder / "cam.json")
    assert runner.invoke(cli, ["train", str(metric_folder), "--camera", cam, "-o",
                               str(model)]).exit_code == 0
    test = metric_folder / "test.png"
    cv2.imwrite(str(test), (draw(np.radians(100)) * 255).astype(np.uint8))
    seen = []
    estimate = PoseEstimator.estimate
    monkeypatch.setattr(PoseEstimator, "estimate",
                        lambda self, *a, **k: seen.append(self.search) or estimate(self, *a, **k))
    r = runner.invoke(cli, ["estimate", str(model), str(test), "--json", "--camera", cam,
                            "--depth-range", "1.2", "1.8"])
    assert r.exit_code == 0, r.output
    est = PoseEstimator.load(model)
    unit = CAM["fy"] * est.object_height_m_ / est.model_.reference_size
    np.testing.assert_allclose(seen[-1].scale_range, (unit / 1.8, unit / 1.2))
    # Those scales only: no image level searches them at other sizes.
    assert seen[-1].image_levels == (1.0,)
    assert json.loads(r.output)["best"]["t_cam_obj_m"][2] == pytest.approx(1.5, rel=0.2)
    # A batch's workers search the same scales.
    seen.clear()
    r = runner.invoke(cli, ["estimate", str(model), str(test), str(test), "--json", "--camera",
                            cam, "--depth-range", "1.2", "1.8"])
    assert r.exit_code == 0, r.output
    assert len(r.output.splitlines()) == 2 and len(seen) == 2
    assert all(np.allclose(o.scale_range, (unit / 1.8, unit / 1.2)) for o in seen)
    r = runner.invoke(cli, ["estimate", str(model), str(test), "--depth-range", "1", "2"])
    assert r.exit_code == 2 and "needs --camera" in r.output
    r = runner.invoke(cli, ["estimate", str(model), str(test), "--camera", cam,
                            "--depth-range", "2", "1"])
    assert r.exit_code == 2 and "nearest < farthest" in r.output
    r = runner.invoke(cli, ["estimate", str(model), str(test), "--camera", cam,
                            "--depth-range", "1", "2", "--scale-range", "0.8", "1.2"])
    assert r.exit_code == 2 and "not both" in r.output
    r = runner.invoke(cli, ["estimate", str(model), str(test), "--camera", cam,
                            "--depth-range", "900", "1000"])
    assert r.exit_code == 2 and "times the training size, outside 0.05-20" in r.output


def test_cli_metric_inputs_refused(metric_folder):
    runner = CliRunner()
    out = str(metric_folder / "m.npz")
    r = runner.invoke(cli, ["train", str(metric_folder), "-o", out])
    assert r.exit_code == 2 and "distance_m column needs the training camera" in r.output
    r = runner.invoke(cli, ["train", str(metric_folder), "--camera", str(metric_folder / "no.json"),
                            "-o", out])
    assert r.exit_code == 1 and "no.json" in r.output
    r = runner.invoke(cli, ["train", str(metric_folder), "--camera", str(metric_folder / "cam.json"),
                            "--object-height-m", "0.2", "-o", out])
    assert r.exit_code == 2 and "not both" in r.output
    text = (metric_folder / "poses.csv").read_text().replace(",1.5\n", ",-2\n", 1)
    (metric_folder / "poses.csv").write_text(text)
    r = runner.invoke(cli, ["train", str(metric_folder), "--camera", str(metric_folder / "cam.json"),
                            "-o", out])
    assert r.exit_code == 1 and "row 2: distance_m must be a positive" in r.output


def _distorted(image, camera):
    """What a lens with ``camera.dist`` makes of ``image`` (seen by the undistorted camera)."""
    h, w = image.shape
    grid = np.stack(np.meshgrid(np.arange(w, dtype=np.float64),
                                np.arange(h, dtype=np.float64)), axis=-1).reshape(-1, 1, 2)
    # Each distorted pixel shows the undistorted image where its ray goes.
    ideal = cv2.undistortPoints(grid, camera.K, np.asarray(camera.dist), P=camera.K)
    maps = ideal.reshape(h, w, 2).astype(np.float32)
    return cv2.remap(image.astype(np.float32), maps[..., 0], maps[..., 1], cv2.INTER_LINEAR)


def test_a_lens_with_distortion_is_undistorted_before_the_search(fitted_estimator, draw):
    camera = Camera(fx=400.0, fy=400.0, cx=320.0, cy=240.0, dist=(-0.3, 0.08, 0.0, 0.0))
    plain = Camera(fx=400.0, fy=400.0, cx=320.0, cy=240.0)
    frame = np.zeros((480, 640))
    frame[300:428, 470:598] = draw(np.radians(100.0))      # near a corner, where it bends
    seen = _distorted(frame, camera)
    truth = fitted_estimator.estimate(frame, camera=plain).best
    fixed = fitted_estimator.estimate(seen, camera=camera).best
    raw = fitted_estimator.estimate(seen, camera=plain).best
    def err(h):
        return float(np.hypot(*np.subtract(h.position, truth.position)))

    assert err(fixed) < 3.0 < err(raw)
    assert abs(fixed.azimuth_deg - truth.azimuth_deg) < 10.0
    assert camera.to_dict()["dist"] == [-0.3, 0.08, 0.0, 0.0]
    assert Camera.from_dict(camera.to_dict()) == camera


@pytest.mark.parametrize("dist", [[0.1, 0.2, 0.3], [float("nan")] * 4, "abcd", [1e9] * 5])
def test_malformed_distortion_is_refused(dist):
    with pytest.raises(ValueError, match="Camera.dist must be OpenCV's distortion"):
        Camera(fx=400.0, fy=400.0, cx=320.0, cy=240.0, dist=dist)
