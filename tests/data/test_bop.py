"""The BOP layout: a scene written, read back as a training set, estimated, results written."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest
from click.testing import CliRunner

from posevote.camera import Camera
from posevote.cli import cli
from posevote.data import object_box
from posevote.data.bop import RESULTS_HEADER, read_bop_scene, results_rows, write_bop_scene
from posevote.geometry import rotation_from_pose

CAMERA = Camera(fx=400.0, fy=400.0, cx=63.5, cy=63.5)


def scene(folder, draw, azimuths_deg, *, distance=1.0):
    """The synthetic object at these azimuths, as a BOP scene at ``distance`` metres."""
    az = np.radians(azimuths_deg)
    views = [draw(a) for a in az]
    boxes = [object_box(v) for v in views]
    rotations = [rotation_from_pose(a, 0.0, 0.0) for a in az]
    translations = [np.array([0.0, 0.0, distance])] * len(az)
    images = [(v * 255).astype(np.uint8) for v in views]
    return write_bop_scene(folder, images, rotations, translations, CAMERA, obj_id=1, boxes=boxes,
                           masks=[v > 0.02 for v in views])


def test_a_scene_reads_back(tmp_path, draw):
    folder = scene(tmp_path / "000003", draw, range(0, 360, 60))
    read = read_bop_scene(folder, obj_id=1)
    assert read.scene_id == 3 and read.im_ids == tuple(range(6))
    np.testing.assert_allclose(np.degrees(read.training_set.poses[:, 0]), range(0, 360, 60),
                               atol=1e-6)
    np.testing.assert_allclose(read.training_set.poses[:, 1:], 0.0, atol=1e-9)
    np.testing.assert_allclose(read.training_set.distances, 1.0)
    assert read.cameras[0] == CAMERA and all(m is not None for m in read.training_set.masks)
    with pytest.raises(ValueError, match="no visible annotation of object 2"):
        read_bop_scene(folder, obj_id=2)


def test_train_estimate_and_write_results(tmp_path, draw):
    train = scene(tmp_path / "train" / "000001", draw, range(0, 360, 20))
    test = scene(tmp_path / "test" / "000002", draw, (50, 130, 290))
    runner = CliRunner()
    model = tmp_path / "m.npz"
    r = runner.invoke(cli, ["train", str(train), "--layout", "bop", "--objects", "1",
                            "-o", str(model)])
    assert r.exit_code == 0, r.output
    out = tmp_path / "results.csv"
    r = runner.invoke(cli, ["bop", str(model), str(test), "--obj-id", "1", "-o", str(out)])
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(io.StringIO(out.read_text())))
    assert out.read_text().splitlines()[0] == RESULTS_HEADER and len(rows) == 3
    for row, az in zip(rows, (50, 130, 290), strict=True):
        assert (row["scene_id"], row["obj_id"]) == ("2", "1")
        R = np.array(row["R"].split(), dtype=float).reshape(3, 3)
        truth = rotation_from_pose(np.radians(az), 0.0, 0.0)
        angle = np.degrees(np.arccos(np.clip((np.trace(R @ truth.T) - 1) / 2, -1, 1)))
        assert angle < 20
        t = np.array(row["t"].split(), dtype=float)
        # Millimetres. The plate's back views between training views read the scale
        # about 15% short (its width changes fastest there); the front ones within 1%.
        assert t[2] == pytest.approx(1000.0, rel=0.05 if az < 180 else 0.25)
        # t names the model's origin (on the optical axis), not the box centre, which
        # lies up to 25 mm to the side.
        assert np.hypot(t[0], t[1]) < 8.0


def test_the_origins_are_the_translations_projected(tmp_path, draw):
    folder = scene(tmp_path / "000004", draw, (0, 90), distance=2.0)
    read = read_bop_scene(folder, obj_id=1)
    # Both at 2 m, the model gives both views that depth: a factor of 1.
    np.testing.assert_allclose(read.training_set.origins, [[CAMERA.cx, CAMERA.cy, 1.0]] * 2)
    gt = json.loads((folder / "scene_gt.json").read_text())
    gt["1"][0]["cam_t_m2c"] = [100.0, -50.0, 500.0]
    (folder / "scene_gt.json").write_text(json.dumps(gt))
    read = read_bop_scene(folder, obj_id=1)
    heights = read.training_set.boxes[:, 3]
    # At 2 m and 0.5 m, where the model gives each view the depth fy H / R.
    model_depth = np.median(heights * [2.0, 0.5]) / np.median(heights)
    np.testing.assert_allclose(read.training_set.origins[1],
                               [CAMERA.cx + 80.0, CAMERA.cy - 40.0, 0.5 / model_depth])
    np.testing.assert_allclose(read.training_set.origins[0, 2], 2.0 / model_depth)
    gt["1"][0]["cam_t_m2c"] = [0.0, 0.0, -500.0]
    (folder / "scene_gt.json").write_text(json.dumps(gt))
    with pytest.raises(ValueError, match="image 1, annotation 0: cam_t_m2c puts the object "
                                         "behind the camera"):
        read_bop_scene(folder, obj_id=1)


def test_bad_scenes_name_the_file(tmp_path, draw):
    folder = scene(tmp_path / "000001", draw, (0, 90))
    gt = json.loads((folder / "scene_gt.json").read_text())
    gt["1"][0]["cam_R_m2c"] = [1, 0, 0, 0, 1, 0, 0, 0, 2]
    (folder / "scene_gt.json").write_text(json.dumps(gt))
    with pytest.raises(ValueError, match=r"scene_gt.json, image 1, annotation 0: cam_R_m2c is not"):
        read_bop_scene(folder, obj_id=1)
    gt["1"][0]["cam_R_m2c"] = [1, 0]
    (folder / "scene_gt.json").write_text(json.dumps(gt))
    with pytest.raises(ValueError, match="expected 9 finite numbers"):
        read_bop_scene(folder, obj_id=1)
    (folder / "scene_camera.json").write_text("{")
    with pytest.raises(ValueError, match="scene_camera.json: not JSON"):
        read_bop_scene(folder, obj_id=1)
    with pytest.raises(FileNotFoundError, match="BOP scene folder not found"):
        read_bop_scene(tmp_path / "none", obj_id=1)
    with pytest.raises(ValueError, match="must be finite"):
        results_rows(1, 2, 3, 0.5, np.eye(3), [np.nan, 0, 0], 0.1)
    r = CliRunner().invoke(cli, ["train", str(folder), "--layout", "bop", "--objects", "1,2",
                                 "-o", str(tmp_path / "m.npz")])
    assert r.exit_code == 2 and "one obj_id" in r.output


@pytest.mark.parametrize(("edit", "message"), [
    (lambda gt, cam, info: gt["0"][0].update(obj_id=True), "annotation 0: obj_id must be a whole"),
    (lambda gt, cam, info: gt["0"][0].update(cam_t_m2c=[0, 0, 1e300]), "farther than 1000 m"),
    (lambda gt, cam, info: cam["0"].update(cam_K=[1e-9, 0, 63.5, 0, 1e-9, 63.5, 0, 0, 1]),
     "at least 1"),
    (lambda gt, cam, info: info.update({"0": {"0": {"visib_fract": 1}}}),
     "scene_gt_info.json, image 0: expected a list"),
])
def test_absurd_scene_values_are_refused(tmp_path, draw, edit, message):
    folder = scene(tmp_path / "000001", draw, (0, 90))
    files = [folder / n for n in ("scene_gt.json", "scene_camera.json", "scene_gt_info.json")]
    data = [json.loads(f.read_text()) for f in files]
    edit(*data)
    for f, d in zip(files, data, strict=True):
        f.write_text(json.dumps(d))
    with pytest.raises(ValueError, match=message):
        read_bop_scene(folder, obj_id=1)


def test_annotation_files_nested_too_deep_twice_keyed_or_huge_are_refused(tmp_path, draw):
    from posevote.data.bop import MAX_BOP_JSON_BYTES

    folder = scene(tmp_path / "000001", draw, (0, 90))
    gt = folder / "scene_gt.json"
    gt.write_text('{"0": ' + "[" * 100_000 + "]" * 100_000 + "}")
    with pytest.raises(ValueError, match="scene_gt.json: the JSON nests too deep"):
        read_bop_scene(folder, obj_id=1)
    gt.write_text('{"0": [], "0": []}')
    with pytest.raises(ValueError, match="scene_gt.json: the key '0' appears twice"):
        read_bop_scene(folder, obj_id=1)
    with gt.open("wb") as fh:            # sparse: no disk is used
        fh.truncate(MAX_BOP_JSON_BYTES + 1)
    with pytest.raises(ValueError, match="scene_gt.json: .* over the limit"):
        read_bop_scene(folder, obj_id=1)


def test_estimating_a_scene_folder_not_named_by_its_id_is_refused(tmp_path, draw,
                                                                  fitted_estimator):
    from posevote.batch import estimate_bop_scene

    folder = scene(tmp_path / "my_scene", draw, (0, 90))
    with pytest.raises(ValueError, match="my_scene: a BOP scene folder is named by its id"):
        estimate_bop_scene(fitted_estimator, folder, obj_id=1)
