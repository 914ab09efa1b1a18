"""Capture: poses, boxes and the camera from photographs of the printed board."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from posevote.camera import Camera
from posevote.capture import (
    R_BOARD_OBJ,
    BoardSpec,
    Footprint,
    capture,
    object_box,
)
from posevote.cli import cli
from posevote.data import read_poses_csv
from posevote.geometry import box_iou, rotation_from_pose

SPEC = BoardSpec(squares=(7, 5), square_m=0.04, marker_m=0.03)
TRUE = Camera(fx=610.0, fy=605.0, cx=322.0, cy=236.0, dist=(-0.12, 0.05, 0.0, 0.0))
FOOT = Footprint(centre_m=(0.14, 0.10), radius_m=0.03, height_m=0.08)
#: Board image pixels per metre in the rendering.
PPM = 4000.0


def _board_image():
    size = (int(SPEC.size_m[0] * PPM), int(SPEC.size_m[1] * PPM))
    return SPEC.board().generateImage(size, marginSize=0)


def _pose(azimuth_deg, elevation_deg, inplane_deg, distance):
    """The board's pose for a camera looking at the object's reference point."""
    R_cam_obj = rotation_from_pose(*np.radians([azimuth_deg, elevation_deg, inplane_deg]))
    R_cam_board = R_cam_obj @ R_BOARD_OBJ.T
    t = np.array([0.0, 0.0, distance]) - R_cam_board @ FOOT.reference_point()
    return R_cam_board, t


def _photo(R, t, board):
    """The board through the lens: a homography of the plane, then the lens's distortion."""
    S = np.diag([1.0 / PPM, 1.0 / PPM, 1.0])
    # Rendered at 4x and averaged down, as a sensor integrates its pixels.
    up = np.array([[4.0, 0.0, 1.5], [0.0, 4.0, 1.5], [0.0, 0.0, 1.0]])
    H = up @ TRUE.K @ np.column_stack([R[:, 0], R[:, 1], t]) @ S
    fine = cv2.warpPerspective(board, H, (2560, 1920), borderValue=200)
    ideal = cv2.resize(fine, (640, 480), interpolation=cv2.INTER_AREA)
    grid = np.stack(np.meshgrid(np.arange(640.0), np.arange(480.0)), axis=-1).reshape(-1, 1, 2)
    maps = cv2.undistortPoints(grid, TRUE.K, np.asarray(TRUE.dist), P=TRUE.K)
    maps = maps.reshape(480, 640, 2).astype(np.float32)
    return cv2.remap(ideal, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderValue=200)


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    folder = tmp_path_factory.mktemp("photos")
    board = _board_image()
    truth = {}
    # Around the object, as a hand holds a camera: heights, tilts and distances varied.
    for k, az in enumerate(range(0, 360, 30)):
        el, ip = (30.0, 45.0, 60.0)[k % 3], (-30.0, -15.0, 0.0, 15.0, 30.0)[k % 5]
        R, t = _pose(az, el, ip, (0.45, 0.55, 0.65, 0.7)[k % 4])
        name = f"p{k:02d}.png"
        cv2.imwrite(str(folder / name), _photo(R, t, board))
        truth[name] = (az, el, ip, R, t, (0.45, 0.55, 0.65, 0.7)[k % 4])
    cv2.imwrite(str(folder / "nothing.png"), np.full((480, 640), 128, np.uint8))
    return folder, truth


def test_capture_recovers_the_camera_poses_and_boxes(photos, tmp_path):
    folder, truth = photos
    report = capture(sorted(folder.glob("*.png")), tmp_path / "set", footprint=FOOT, spec=SPEC)
    cam = report.camera
    for name in ("fx", "fy", "cx", "cy"):
        assert getattr(cam, name) == pytest.approx(getattr(TRUE, name), rel=0.01)
    assert report.calibration_rms_px < 0.5
    assert [why for name, why in report.refused] == [
        "the board is not found (fewer than 6 corners)"]
    assert report.refused[0][0].endswith("nothing.png")
    ts = read_poses_csv(tmp_path / "set")
    assert len(ts) == len(truth)
    for path, pose, box, dist, mask in zip(ts.images, ts.poses, ts.boxes, ts.distances,
                                           ts.masks, strict=True):
        az, el, ip, R, t, distance = truth[path.name]
        error = np.degrees(np.arccos(np.clip((np.trace(
            rotation_from_pose(*pose).T @ rotation_from_pose(*np.radians([az, el, ip]))) - 1)
            / 2, -1, 1)))
        assert error < 1.0
        assert dist == pytest.approx(distance, rel=0.01)
        # Nothing stands on these boards: no mask is cut, and the box is the cylinder's.
        assert mask is None
        assert box_iou(box, object_box(R, t, FOOT, Camera(fx=TRUE.fx, fy=TRUE.fy, cx=TRUE.cx,
                                                           cy=TRUE.cy))) > 0.85
    written = json.loads((tmp_path / "set" / "camera.json").read_text())
    assert len(written["dist"]) == 5 and written["dist"][0] == pytest.approx(-0.12, abs=0.03)


def test_the_board_command_and_capture_from_the_command_line(photos, tmp_path):
    folder, truth = photos
    r = CliRunner().invoke(cli, ["board", "-o", str(tmp_path / "board.png"), "--squares", "7",
                                 "5", "--square-mm", "40", "--marker-mm", "30", "--dpi", "150"])
    assert r.exit_code == 0, r.output
    assert BoardSpec.read(tmp_path / "board.json") == SPEC
    printed = cv2.imread(str(tmp_path / "board.png"), cv2.IMREAD_GRAYSCALE)
    assert printed.shape[1] == pytest.approx((0.28 + 0.02) / 0.0254 * 150, abs=2)
    r = CliRunner().invoke(cli, ["capture", str(folder), "-o", str(tmp_path / "set"),
                                 "--board", str(tmp_path / "board.json"), "--centre-mm", "140",
                                 "100", "--radius-mm", "30", "--height-mm", "80"])
    assert r.exit_code == 0, r.output
    assert "nothing.png: the board is not found" in r.output
    assert len(read_poses_csv(tmp_path / "set")) == len(truth)
    # What it wrote trains, and its camera file is read back.
    r = CliRunner().invoke(cli, ["train", str(tmp_path / "set"), "--object-height-m", "0.08",
                                 "-o", str(tmp_path / "m.npz")])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(cli, ["estimate", str(tmp_path / "m.npz"),
                                 str(tmp_path / "set" / "p00.png"), "--camera",
                                 str(tmp_path / "set" / "camera.json")])
    assert r.exit_code in (0, 3) and "Error" not in r.output, r.output


def test_too_few_photographs_to_calibrate_say_so(photos, tmp_path):
    folder, _ = photos
    with pytest.raises(ValueError, match="needs the board in at least 4 photographs"):
        capture(sorted(folder.glob("p0[0-2].png")), tmp_path / "set", footprint=FOOT, spec=SPEC)
    report = capture(sorted(folder.glob("p0[0-2].png")), tmp_path / "set", footprint=FOOT,
                     spec=SPEC, camera=TRUE)
    assert len(report.kept) == 3 and report.calibration_rms_px is None


def test_capture_never_writes_over_its_photographs(photos, tmp_path):
    folder, _ = photos
    before = sorted((p.name, p.stat().st_mtime_ns) for p in folder.iterdir())
    with pytest.raises(ValueError, match="holds the photographs themselves"):
        capture(sorted(folder.glob("*.png")), folder, footprint=FOOT, spec=SPEC)
    assert sorted((p.name, p.stat().st_mtime_ns) for p in folder.iterdir()) == before


@pytest.mark.parametrize(("make", "message"), [
    (lambda: BoardSpec(squares=(2, 5)), "BoardSpec.squares"),
    (lambda: BoardSpec(square_m=0.04, marker_m=0.05), "BoardSpec.marker_m"),
    (lambda: BoardSpec(dictionary="DICT_NOPE"), "BoardSpec.dictionary"),
    (lambda: Footprint(centre_m=(0.1, 0.1), radius_m=0.0, height_m=0.1), "Footprint.radius_m"),
    (lambda: Footprint(centre_m=(np.nan, 0.1), radius_m=0.05, height_m=0.1), "centre_m"),
])
def test_absurd_boards_and_footprints_are_refused(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_a_board_file_that_is_not_one_names_itself(tmp_path):
    (tmp_path / "b.json").write_text('{"squares": [7, 5], "square_m": "big"}')
    with pytest.raises(ValueError, match="b.json"):
        BoardSpec.read(tmp_path / "b.json")
