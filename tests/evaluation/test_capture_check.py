"""The rendered capture check: photographs of a textured object on the board, end to end."""

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from posevote.cli import cli
from posevote.evaluation.capture_check import (
    LENS,
    CaptureSetup,
    board_pose,
    distort,
    draw_pose,
    footprint,
    run_capture_check,
)

pytest.importorskip("pybullet")


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    out = tmp_path_factory.mktemp("capture-check")
    return out, run_capture_check(CaptureSetup(photos=24, tests=12), out)


def test_capture_from_rendered_photographs_recovers_the_camera_poses_and_masks(small):
    out, s = small
    assert s["kept"] == 24 and s["refused"] == []
    assert max(s["intrinsics_error_pct"].values()) < 1.0
    assert s["calibration_rms_px"] < 0.5
    assert s["rotation_deg"]["max"] < 1.0
    assert s["distance_pct"]["max"] < 1.0
    # The masks cut the object from the board's squares, and its box is the object's.
    assert s["mask_iou"]["masked"] == 24 and s["mask_iou"]["median"] > 0.9
    assert s["box_iou"]["median"] > 0.9
    assert (out / "captured" / "masks").is_dir()
    assert json.loads((out / "summary.json").read_text())["kept"] == 24
    assert "captured over true" in (out / "report.md").read_text()


def test_a_model_of_the_captured_folder_poses_as_one_of_the_truth(small):
    _, s = small
    captured, true = (np.array(s["errors_deg"][k]) for k in ("captured", "true"))
    assert len(captured) == len(true) == 12
    # Twelve tests are few (one half-turn moves the mean by 15 degrees; six were too few):
    # benchmarks/capture_check.py measures this over 144; here the chain runs end to end and
    # the captured model is not far worse on average.
    assert np.mean(captured) <= 1.5 * np.mean(true) + 5.0


def test_the_board_in_the_render_is_where_capture_puts_it():
    foot = footprint(CaptureSetup())
    R, t = draw_pose(np.random.default_rng(3), 40.0, foot)
    Rb, tb = board_pose(R, t, foot)
    # The footprint's centre is the object's origin, on the board's plane.
    centre = np.array([foot.centre_m[0], foot.centre_m[1], 0.0])
    assert np.allclose(Rb @ centre + tb, t)
    assert np.allclose(Rb @ np.array([1.0, 0, 0]), R @ np.array([1.0, 0, 0]))


def test_distort_moves_pixels_as_the_lens_does():
    image = np.zeros((480, 640), np.float32)
    image[100, 600] = 1.0
    seen = distort(image)
    row, col = np.unravel_index(np.argmax(seen), seen.shape)
    expected = cv2.projectPoints(np.array([[(600 - LENS.cx) / LENS.fx,
                                            (100 - LENS.cy) / LENS.fy, 1.0]]),
                                 np.zeros(3), np.zeros(3), LENS.K, np.asarray(LENS.dist))[0]
    assert abs(col - expected[0, 0, 0]) <= 1 and abs(row - expected[0, 0, 1]) <= 1
    # Barrel distortion pulls a corner's point toward the centre.
    assert col < 600 and row > 100


def test_setup_refuses_what_it_cannot_run():
    for bad in ({"mesh": "teapot.urdf"}, {"photos": 2}, {"tests": 0}, {"seed": -1}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            CaptureSetup(**bad)


def test_the_command_line_refuses_options_it_does_not_use(tmp_path):
    r = CliRunner().invoke(cli, ["evaluate", "rendered-capture", "--out", str(tmp_path / "o"),
                                 "--jobs", "2"])
    assert r.exit_code == 2 and "not used by rendered-capture" in r.output
