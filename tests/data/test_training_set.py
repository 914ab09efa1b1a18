import cv2
import numpy as np
import pytest

from posevote.data import read_coil, read_epfl, read_poses_csv, write_poses_csv


def make_folder(tmp_path, rows, header="image,azimuth_deg", n_images=2):
    for i in range(n_images):
        cv2.imwrite(str(tmp_path / f"im{i}.png"), np.full((20, 30), 100, np.uint8))
    (tmp_path / "poses.csv").write_text(header + "\n" + "\n".join(rows) + "\n")
    return tmp_path


def test_reads_minimal_csv(tmp_path):
    ts = read_poses_csv(make_folder(tmp_path, ["im0.png,10", "im1.png,370"]))
    assert len(ts) == 2
    assert np.allclose(np.degrees(ts.poses[:, 0]), [10, 370])
    assert np.all(np.isnan(ts.boxes))


def test_reads_full_csv_and_round_trips(tmp_path):
    header = ("image,azimuth_deg,elevation_deg,inplane_deg,box_x,box_y,box_w,box_h,mask,"
              "instance,category")
    folder = make_folder(tmp_path, ["im0.png,10,5,2,1,2,10,8,,a,mug", "im1.png,20,5,0,0,0,5,5,,b,mug"],
                         header=header)
    ts = read_poses_csv(folder)
    assert ts.category == "mug" and ts.instances == ("a", "b")
    assert ts.boxes[0].tolist() == [1, 2, 10, 8]
    write_poses_csv(ts, folder)
    again = read_poses_csv(folder)
    assert np.allclose(again.poses, ts.poses) and np.allclose(again.boxes, ts.boxes)
    assert ts.origins.shape == again.origins.shape == (0, 2)


def test_reads_and_writes_the_origin_columns(tmp_path):
    folder = make_folder(tmp_path, ["im0.png,10,12.5,7", "im1.png,20,14,6.25"],
                         header="image,azimuth_deg,origin_u,origin_v")
    ts = read_poses_csv(folder)
    np.testing.assert_allclose(ts.origins, [[12.5, 7.0], [14.0, 6.25]])
    np.testing.assert_allclose(ts.subset([1]).origins, [[14.0, 6.25]])
    # Written with empty box fields (no boxes): read back as no box, not refused.
    write_poses_csv(ts, folder)
    again = read_poses_csv(folder)
    np.testing.assert_allclose(again.origins, ts.origins)
    assert np.all(np.isnan(again.boxes))


@pytest.mark.parametrize(
    ("rows", "header", "message"),
    [
        (["im0.png,abc"], "image,azimuth_deg", r"row 2: column 'azimuth_deg' must be a number"),
        (["im0.png,nan"], "image,azimuth_deg", r"row 2: column 'azimuth_deg' is 'nan'"),
        (["im0.png,10", "im1.png,"], "image,azimuth_deg", r"row 3: column 'azimuth_deg'"),
        (["im0.png"], "image,elevation_deg", r"missing column 'azimuth_deg'"),
        (["im0.png,1,2"], "image,azimuth_deg,box_x", r"all four box columns"),
        (["im0.png,1,0,0,5,-1"], "image,azimuth_deg,box_x,box_y,box_w,box_h",
         r"row 2: box width and height must be positive"),
        (["im0.png,1,0,,5,5"], "image,azimuth_deg,box_x,box_y,box_w,box_h",
         r"row 2: column 'box_y' must be a number"),
        (["im0.png,1,95"], "image,azimuth_deg,elevation_deg", r"elevation_deg must be in"),
        ([], "image,azimuth_deg", r"no rows"),
        (["im0.png,1,extra"], "image,azimuth_deg", r"row 2: more fields"),
        (["im0.png,1,3"], "image,azimuth_deg,origin_u", r"both origin columns"),
        (["im0.png,1,3,"], "image,azimuth_deg,origin_u,origin_v",
         r"row 2: column 'origin_v' must be a number"),
    ],
)
def test_malformed_csv(tmp_path, rows, header, message):
    with pytest.raises(ValueError, match=message):
        read_poses_csv(make_folder(tmp_path, rows, header=header))


def test_missing_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="training folder not found"):
        read_poses_csv(tmp_path / "none")
    with pytest.raises(FileNotFoundError, match="needs a poses.csv"):
        read_poses_csv(tmp_path)
    with pytest.raises(FileNotFoundError, match="row 2: image file not found"):
        read_poses_csv(make_folder(tmp_path, ["missing.png,10"]))


def test_coil_reader(coil_dir):
    ts = read_coil(coil_dir, objects=[6], azimuths_deg=range(0, 360, 20))
    assert len(ts) == 18 and ts.instances[0] == "obj6"
    assert np.allclose(np.degrees(ts.poses[:, 0]), np.arange(0, 360, 20))
    x, y, w, h = ts.boxes[0]
    assert 0 <= x and x + w <= 128 and 20 < w <= 128 and 20 < h <= 128
    with pytest.raises(FileNotFoundError, match="no views of object 2"):
        read_coil(coil_dir, objects=[2])


def test_epfl_reader(epfl_dir):
    ts = read_epfl(epfl_dir, cars=[1])
    assert len(ts) == 118
    az = np.degrees(ts.poses[:, 0])
    front = [int(x) for x in (epfl_dir / "tripod-seq.txt").read_text().splitlines()[5].split()][0]
    assert az[front - 1] == pytest.approx(0.0)
    # the sequence turns steadily: consecutive azimuth steps are small
    steps = np.abs((np.diff(az) + 180) % 360 - 180)
    assert np.median(steps) < 5
    with pytest.raises(ValueError, match="car 99 is not in"):
        read_epfl(epfl_dir, cars=[99])


def test_object_height_from_the_distances(tmp_path):
    from posevote.camera import Camera

    cam = Camera(fx=500.0, fy=500.0, cx=10.0, cy=10.0)
    header = "image,azimuth_deg,box_x,box_y,box_w,box_h,distance_m"
    ts = read_poses_csv(make_folder(tmp_path, ["im0.png,0,0,0,10,10,2", "im1.png,20,0,0,10,20,2"],
                                    header=header))
    assert ts.object_height_m(cam) == pytest.approx(np.median([10 * 2 / 500, 20 * 2 / 500]))
    partial = read_poses_csv(make_folder(tmp_path, ["im0.png,0,0,0,10,10,2", "im1.png,20,0,0,10,20,"],
                                         header=header))
    with pytest.raises(ValueError, match="needs a distance_m in every row"):
        partial.object_height_m(cam)
    no_box = read_poses_csv(make_folder(tmp_path, ["im0.png,0,1", "im1.png,20,1"],
                                        header="image,azimuth_deg,distance_m"))
    with pytest.raises(ValueError, match="needs the box columns"):
        no_box.object_height_m(cam)
