"""Bad input, tried as a user would, through the command line and the API.

Every case asserts the exit code (or the exception type) and that the
message names the file, row, column, array or option at fault. The memory
cases run in a child process under a capped address space: they finish at
once because the limit is checked before anything large is allocated.
"""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
import time
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from posevote import PoseEstimator
from posevote.cli import cli

# --- fixtures -----------------------------------------------------------------------


@pytest.fixture(scope="module")
def folder(training_folder):
    return training_folder


@pytest.fixture(scope="module")
def model(saved_model):
    return saved_model


@pytest.fixture(scope="module")
def image(tmp_path_factory, draw):
    path = tmp_path_factory.mktemp("img") / "test.png"
    cv2.imwrite(str(path), (draw(np.radians(100)) * 255).astype(np.uint8))
    return path


def invoke(*args: str):
    return CliRunner().invoke(cli, [str(a) for a in args])


def png_bomb(path: Path, width: int, height: int) -> Path:
    """A small PNG file that decodes to ``width x height`` grey pixels."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))

    comp = zlib.compressobj(9)
    row = b"\0" * (width + 1)
    body = b"".join(comp.compress(row) for _ in range(height)) + comp.flush()
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height,
                                                                      8, 0, 0, 0, 0))
                     + chunk(b"IDAT", body) + chunk(b"IEND", b""))
    return path


# --- output paths -----------------------------------------------------------------------

def test_train_output_naming_a_folder(folder, tmp_path):
    r = invoke("train", folder, "-o", tmp_path)
    assert r.exit_code == 2 and "is a folder" in r.output and "-o" in r.output


def test_train_output_under_a_file(folder, tmp_path):
    (tmp_path / "f").write_text("x")
    r = invoke("train", folder, "-o", tmp_path / "f" / "m.npz")
    assert r.exit_code == 2 and "is a file" in r.output


@pytest.mark.parametrize("name", ["overlay", "overlay.txt", "."])
def test_overlay_without_an_image_suffix(model, image, tmp_path, name):
    r = invoke("estimate", model, image, "--overlay", tmp_path / name)
    assert r.exit_code == 2 and "--overlay" in r.output


def test_overlay_in_a_missing_folder_is_made(model, image, tmp_path):
    out = tmp_path / "new" / "deeper" / "o.png"
    r = invoke("estimate", model, image, "--overlay", out)
    assert r.exit_code == 0 and out.is_file()


def test_evaluate_out_naming_a_file(tmp_path):
    (tmp_path / "f").write_text("x")
    r = invoke("evaluate", "coil-category", "--data", tmp_path, "--out", tmp_path / "f")
    assert r.exit_code == 2 and "--out" in r.output and "is a file" in r.output


def test_weights_output_suffix_and_demo_output_file(model, tmp_path):
    r = invoke("weights", model, "-o", tmp_path / "w")
    assert r.exit_code == 2 and "-o" in r.output
    (tmp_path / "f").write_text("x")
    r = invoke("demo", "-o", tmp_path / "f")
    assert r.exit_code == 2 and "is a file" in r.output


# --- option values ----------------------------------------------------------------------

@pytest.mark.parametrize("step", ["0", "400", "-5", "nan", "inf", "7"])
def test_azimuth_step(tmp_path, step):
    r = invoke("train", tmp_path, "--layout", "coil", "--objects", "6", "--azimuth-step-deg",
               step, "-o", tmp_path / "m.npz")
    assert r.exit_code == 2 and "--azimuth-step-deg" in r.output


@pytest.mark.parametrize("option", [["--objects", "6"], ["--cars", "1"],
                                    ["--azimuth-step-deg", "20"]])
def test_layout_options_on_the_wrong_layout(folder, tmp_path, option):
    r = invoke("train", folder, *option, "-o", tmp_path / "m.npz")
    assert r.exit_code == 2 and option[0] in r.output and "applies to" in r.output


@pytest.mark.parametrize(("option", "values", "name"), [
    ("--scale-range", ["1", "inf"], "scale_range"),
    ("--scale-range", ["1", "1e6"], "scale_range"),
    ("--scale-range", ["0", "1"], "scale_range"),
    ("--scale-range", ["nan", "1"], "scale_range"),
    ("--scale-range", ["2", "1"], "scale_range"),
    ("--inplane-range-deg", ["-400", "400"], "inplane_range_deg"),
    ("--inplane-range-deg", ["nan", "0"], "inplane_range_deg"),
    ("--min-score", ["nan"], "min_score"),
    ("--min-score", ["inf"], "min_score"),
])
def test_estimate_option_values(model, image, option, values, name):
    r = invoke("estimate", model, image, option, *values)
    assert r.exit_code == 1 and r.output.startswith("Error:") and name in r.output


@pytest.mark.parametrize("threads", ["0", "1000", "two"])
def test_estimate_threads(model, image, threads):
    r = invoke("estimate", model, image, "--threads", threads)
    assert r.exit_code == 2 and "--threads" in r.output


@pytest.mark.parametrize(("param", "name"), [
    ("search.scale_steps=1e9", "scale_steps"),
    ("search.scale_steps=1000000000", "scale_steps"),
    ("search.scale_steps=0", "scale_steps"),
    ("search.scale_steps=-3", "scale_steps"),
    ("kernel.position_sigma=-1", "position_sigma"),
    ("kernel.position_sigma=1e308", "position_sigma"),
    ("search.inplane_step_deg=0.0001", "inplane_step_deg"),
    ("search.viewpoint_step_deg=0", "viewpoint_step_deg"),
    ("max_modes=0", "max_modes"),
    ("n_jobs=10000", "n_jobs"),
    ("weights=2", "weights"),
    ("edges.thresholds=(0.5, 0.1)", "thresholds"),
    ("edges.thresholds='ab'", "thresholds"),
    ("search.scale_range=(1, 1e6)", "scale_range"),
    ("kernel.position_sigma=nan", "position_sigma"),       # a word: refused by its group
    ("search.rerank=templates", "rerank"),
])
def test_train_param_values(folder, tmp_path, param, name):
    out = tmp_path / "m.npz"
    r = invoke("train", folder, "--param", param, "-o", out)
    assert r.exit_code == 1 and name in r.output and not out.exists()


@pytest.mark.parametrize(("param", "text"), [
    ("nosuch=1", "unknown estimator parameter"),
    ("search.nosuch=1", "unknown estimator parameter"),
    ("search=1", "one by one"),
    ("kernel.position_sigma=(1,", "neither a Python literal"),
    ("kernel.position_sigma", "NAME=VALUE"),
    ("kernel.position_sigma=" + "-" * 100_000 + "1", "at most 1,000"),
])
def test_train_param_syntax(folder, tmp_path, param, text):
    r = invoke("train", folder, "--param", param, "-o", tmp_path / "m.npz")
    assert r.exit_code == 2 and text in r.output and "--param" in r.output


@pytest.mark.parametrize(("option", "value"), [("--cars", "1-1000000000"), ("--cars", "5-1"),
                                               ("--cars", "1-"), ("--objects", "a,b")])
def test_number_lists(tmp_path, option, value):
    layout = "epfl" if option == "--cars" else "coil"
    r = invoke("train", tmp_path, "--layout", layout, option, value, "-o", tmp_path / "m.npz")
    assert r.exit_code == 2 and option in r.output and value in r.output


def test_unknown_preset_is_a_usage_error(folder, tmp_path):
    r = invoke("train", folder, "--preset", "nosuch", "-o", tmp_path / "m.npz")
    assert r.exit_code == 2 and "unknown preset 'nosuch'" in r.output and "--preset" in r.output
    r = invoke("evaluate", "frames", "--preset", "nosuch", "--out", tmp_path / "f")
    assert r.exit_code == 2 and "unknown preset 'nosuch'" in r.output


def test_a_misspelt_param_gets_the_near_name(folder, tmp_path):
    r = invoke("train", folder, "--param", "search.scale_rnage=(0.8,1.2)", "-o",
               tmp_path / "m.npz")
    assert r.exit_code == 2 and "did you mean 'search.scale_range'?" in r.output


@pytest.mark.parametrize("args", [["evaluate", "epfl-cv", "--data", ".", "--every", "0"],
                                  ["evaluate", "epfl-cv", "--data", ".", "--jobs", "0"],
                                  ["demo", "--images", "0"], ["demo", "--seed", "-1"]])
def test_command_ranges(args):
    r = invoke(*args)
    assert r.exit_code == 2 and args[-2] in r.output


def test_weights_views_range(model, tmp_path):
    r = invoke("weights", model, "-o", tmp_path / "w.png", "--views", "0")
    assert r.exit_code == 2 and "--views" in r.output


# --- model files ------------------------------------------------------------------------

def rewrite(model: Path, out: Path, *, header=None, **arrays) -> Path:
    """A copy of ``model`` with some arrays replaced and its header edited."""
    with np.load(model) as data:
        content = {k: data[k] for k in data.files}
    head = json.loads(bytes(content["header"]).decode())
    if header is not None:
        header(head)
    content["header"] = np.frombuffer(json.dumps(head).encode(), dtype=np.uint8)
    for name, edit in arrays.items():
        content[name] = edit(content[name].copy())
    np.savez(out, **content)
    return out


def _set(value, index=0):
    def edit(a):
        a.flat[index] = value
        return a
    return edit


def _params(group, field, value):
    def edit(head):
        head["params"][group][field] = value
    return edit


@pytest.mark.parametrize(("case", "arrays", "header", "text"), [
    ("nan-xy", {"xy": _set(np.nan)}, None, "xy"),
    ("inf-weight", {"weight": _set(np.inf)}, None, "weight"),
    ("negative-weight", {"weight": _set(-1.0)}, None, "weight"),
    ("nan-theta", {"theta": _set(np.nan)}, None, "theta"),
    ("nan-box", {"view_box": _set(np.nan)}, None, "view_box"),
    ("zero-box", {"view_box": _set(0.0)}, None, "view_box"),
    ("inf-azimuth", {"view_azimuth": _set(np.inf)}, None, "view_azimuth"),
    ("view-out-of-range", {"view": _set(10_000)}, None, "array shapes"),
    ("instance-out-of-range", {"view_instance": _set(7)}, None, "view_instance"),
    ("short-weight", {"weight": lambda a: a[:-1]}, None, "array weight declares shape"),
    ("version-string", {}, lambda h: h.update(version="2"), "'2' is not an integer"),
    ("version-new", {}, lambda h: h.update(version=99), "newer"),
    ("version-old", {}, lambda h: h.update(version=2), "older"),
    ("foreign-format", {}, lambda h: h.update(format="other"), "not a posevote model"),
    ("sigma-string", {}, _params("kernel", "position_sigma", "wide"), "position_sigma"),
    ("steps-huge", {}, _params("search", "scale_steps", 10**9), "scale_steps"),
    ("steps-float", {}, _params("search", "scale_steps", 3.5), "scale_steps"),
    ("range-inf", {}, _params("search", "scale_range", [1, 1e400]), "scale_range"),
    ("unknown-field", {}, _params("search", "nosuch", 1), "nosuch"),
    ("unknown-param", {}, lambda h: h["params"].update(nosuch=1), "nosuch"),
    ("names-not-list", {}, lambda h: h.update(instance_names=5), "instance_names"),
    ("reference-string", {}, lambda h: h.update(reference_size="big"), "reference_size"),
    ("kappa-negative", {}, lambda h: h["extra"].update(viewpoint_kappa=-1), "viewpoint_kappa"),
    ("params-list", {}, lambda h: h.update(params=[1]), "params"),
    ("theta-2d", {"theta": lambda a: a[:, None]}, None, "array theta declares shape"),
    ("theta-absurd", {"theta": _set(1e300)}, None, "theta has values past"),
    ("azimuth-absurd", {"view_azimuth": _set(1e300)}, None, "view_azimuth has values past"),
    ("view-float", {"view": lambda a: a.astype(np.float64)}, None, "array view declares"),
    ("xy-complex", {"xy": lambda a: a.astype(np.complex128)}, None, "not real numbers"),
    ("xy-long", {"xy": lambda a: np.zeros((len(a) * 1000, 2))}, None, "array xy declares"),
])
def test_bad_model_files(model, tmp_path, image, case, arrays, header, text):
    bad = rewrite(model, tmp_path / f"{case}.npz", header=header, **arrays)
    with pytest.raises(ValueError, match=f"{case}.npz") as info:
        PoseEstimator.load(bad)
    assert text in str(info.value)
    r = invoke("estimate", bad, image)
    assert r.exit_code == 1 and f"{case}.npz" in r.output and text in r.output


def test_an_int_where_a_float_is_expected_is_read(model, tmp_path, image):
    ok = rewrite(model, tmp_path / "int.npz", header=_params("kernel", "position_sigma", 3))
    est = PoseEstimator.load(ok)
    assert isinstance(est.kernel.position_sigma, float)
    assert invoke("weights", ok, "-o", tmp_path / "w.png").exit_code == 0
    assert invoke("estimate", ok, image).exit_code == 0


@pytest.mark.parametrize(("case", "make", "text"), [
    ("text", lambda p, m: p.write_text("not a model"), "not a posevote model"),
    ("truncated", lambda p, m: p.write_bytes(m.read_bytes()[:len(m.read_bytes()) // 2]),
     "model"),
    ("empty", lambda p, m: p.write_bytes(b""), "not a posevote model"),
    ("no-header", lambda p, m: np.savez(p, xy=np.zeros((2, 2))), "no header"),
    ("pickled", lambda p, m: np.savez(p, header=np.array([{"a": 1}], dtype=object)),
     "cannot be loaded when allow_pickle=False"),
])
def test_foreign_and_corrupt_model_files(model, tmp_path, image, case, make, text):
    bad = tmp_path / f"{case}.npz"
    make(bad, model)
    with pytest.raises(ValueError, match=f"{case}.npz"):
        PoseEstimator.load(bad)
    r = invoke("estimate", bad, image)
    assert r.exit_code == 1 and f"{case}.npz" in r.output and text in r.output


def test_load_type_and_missing(tmp_path):
    with pytest.raises(TypeError, match="str or Path"):
        PoseEstimator.load(123)
    with pytest.raises(FileNotFoundError, match="nope.npz"):
        PoseEstimator.load(tmp_path / "nope.npz")
    r = invoke("estimate", tmp_path, tmp_path / "x.png")
    assert r.exit_code == 1 and "model file not found" in r.output


# --- images -----------------------------------------------------------------------------

def _noise(shape=(64, 64)):
    return (np.random.default_rng(0).random(shape) * 255).astype(np.uint8)


def _truncated_jpeg(p):
    data = cv2.imencode(".jpg", _noise())[1].tobytes()
    p.write_bytes(data[:len(data) * 6 // 10])


def _truncated_png(p):
    data = cv2.imencode(".png", _noise())[1].tobytes()
    p.write_bytes(data[:len(data) // 2])


def _edited_jpeg(p, edit):
    p.write_bytes(edit(cv2.imencode(".jpg", _noise())[1].tobytes()))


def _bad_crc_png(p):
    data = bytearray(cv2.imencode(".png", _noise())[1].tobytes())
    data[data.find(b"IDAT") + 20] ^= 0xFF
    p.write_bytes(bytes(data))


@pytest.mark.parametrize(("name", "make", "text"), [
    ("cut.jpg", _truncated_jpeg, "truncated"),
    ("cut.png", _truncated_png, "truncated"),
    ("crc.png", _bad_crc_png, "damaged"),
    ("scan.jpg", lambda p: _edited_jpeg(p, lambda b: b[:len(b) // 2] + b"\xff\xd0\xff\xd0"
                                        + b[len(b) // 2:]), "Corrupt JPEG data"),
    ("flip.jpg", lambda p: _edited_jpeg(p, lambda b: b[:600] + bytes([b[600] ^ 0xFF])
                                        + b[601:]), "Corrupt JPEG data"),
    ("tail.jpg", lambda p: _edited_jpeg(p, lambda b: b[:-2] + b"\0\0\0" + b[-2:]),
     "extraneous bytes"),
    ("text.png", lambda p: p.write_text("hello"), "cannot decode"),
    ("empty.png", lambda p: p.write_bytes(b""), "cannot decode"),
    ("folder.png", lambda p: p.mkdir(), "holds no image"),
])
def test_bad_image_files(model, tmp_path, name, make, text):
    path = tmp_path / name
    make(path)
    r = invoke("estimate", model, path)
    assert r.exit_code == 1 and name in r.output and text in r.output
    with pytest.raises((ValueError, FileNotFoundError), match=name):
        PoseEstimator.load(model).estimate(path)


def test_a_truncated_training_image(folder, tmp_path):
    import shutil

    copy = tmp_path / "t"
    shutil.copytree(folder, copy)
    _truncated_png(copy / "v03.png")
    r = invoke("train", copy, "-o", tmp_path / "m.npz")
    assert r.exit_code == 1 and "v03.png" in r.output and not (tmp_path / "m.npz").exists()


def _capped(code: str, cap_gib: float = 3.0) -> subprocess.CompletedProcess:
    """Run ``code`` in a child Python under an address-space cap."""
    prelude = ("import resource; resource.setrlimit(resource.RLIMIT_AS, "
               f"({int(cap_gib * 2**30)}, {int(cap_gib * 2**30)}))\n")
    return subprocess.run([sys.executable, "-c", prelude + code], capture_output=True,
                          text=True, timeout=120)


def test_a_png_bomb_is_refused_before_decoding(model, tmp_path):
    bomb = png_bomb(tmp_path / "bomb.png", 10_000, 10_000)
    assert bomb.stat().st_size < 1_000_000
    start = time.perf_counter()
    proc = _capped("from posevote.cli import main; import sys; "
                   f"sys.argv = ['posevote', 'estimate', {str(model)!r}, {str(bomb)!r}]; main()")
    assert proc.returncode == 1, proc.stderr
    assert "bomb.png" in proc.stderr and "over the limit" in proc.stderr
    assert time.perf_counter() - start < 60


def _rle_scanline(width: int) -> bytes:
    """One Radiance scanline of ``width`` black pixels, run-length coded."""
    runs = b"".join(bytes([128 + min(127, width - i), 0]) for i in range(0, width, 127))
    return bytes([2, 2, width >> 8, width & 255]) + runs * 4


@pytest.mark.parametrize("kind", ["hdr", "pfm"])
def test_formats_pillow_does_not_read_are_sized_before_decoding(model, tmp_path, kind):
    bomb = tmp_path / f"bomb.{kind}"
    if kind == "hdr":   # 16000 x 16000 pixels in 8 MB
        bomb.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 16000 +X 16000\n"
                         + _rle_scanline(16000) * 16000)
    else:
        bomb.write_bytes(b"PF\n16000 16000\n-1.0\n" + b"\0" * 1000)
    proc = _capped("from posevote.cli import main; import sys; "
                   f"sys.argv = ['posevote', 'estimate', {str(model)!r}, {str(bomb)!r}]; main()")
    assert proc.returncode == 1, proc.stderr
    assert f"bomb.{kind}" in proc.stderr and "over the limit" in proc.stderr
    # A small one is read.
    from posevote.data import read_image

    small = tmp_path / f"small.{kind}"
    cv2.imwrite(str(small), np.random.default_rng(0).random((20, 30, 3)).astype(np.float32))
    assert read_image(small).shape == (20, 30)


def test_the_pixel_limit_is_configurable(model, image, tmp_path):
    env = {**os.environ, "POSEVOTE_MAX_IMAGE_PIXELS": "1000"}
    proc = subprocess.run([sys.executable, "-m", "posevote.cli", "estimate", str(model),
                           str(image)], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 1 and "test.png" in proc.stderr and "1,000" in proc.stderr


def test_a_huge_array_is_refused(fitted_estimator):
    big = np.lib.stride_tricks.as_strided(np.zeros(1, np.uint8), shape=(10_000, 10_000),
                                          strides=(0, 0))
    with pytest.raises(ValueError, match="frame: the image is 10000 x 10000"):
        from posevote.data.images import as_gray_float

        as_gray_float(big, name="frame")
    with pytest.raises(ValueError, match="over the limit"):
        fitted_estimator.estimate(big)


def test_the_search_maps_are_sized_before_allocation(model, tmp_path):
    # A tiny scale on a large image asks for maps of (4000/0.05)^2 pixels per
    # orientation: refused at once, under a cap far below what it would take.
    proc = _capped(
        "import numpy as np\n"
        "from posevote import PoseEstimator\n"
        f"est = PoseEstimator.load({str(model)!r})\n"
        "est.set_params(search__scale_range=(0.05, 0.06), search__object_kernel=True)\n"
        "img = np.zeros((2000, 2000)); img[500:1500, 900:1100] = 1.0\n"
        "try:\n    est.estimate(img)\nexcept ValueError as e:\n    print('refused:', e)\n")
    assert proc.returncode == 0, proc.stderr
    assert "refused:" in proc.stdout and "GiB" in proc.stdout and "scale_range" in proc.stdout


# --- poses.csv --------------------------------------------------------------------------

def make_csv(folder: Path, tmp_path: Path, text: str | bytes, *, name="poses.csv") -> Path:
    """A copy of the training folder's images with another poses.csv."""
    import shutil

    out = tmp_path / "set"
    shutil.copytree(folder, out)
    target = out / name
    target.write_bytes(text if isinstance(text, bytes) else text.encode())
    return out


@pytest.mark.parametrize(("text", "message"), [
    ("image,azimuth_deg,elevaton_deg\nv00.png,0,0\n", "did you mean 'elevation_deg'"),
    ("image,azimuth_deg,notes\nv00.png,0,x\n", "unknown column(s) 'notes'"),
    ("image,azimuth_deg,azimuth_deg\nv00.png,0,0\n", "'azimuth_deg' appears twice"),
    ("image,azimuth_deg\nv00.png,0\nv01.png,20\nv00.png,0\n", "row 4: image 'v00.png' is already"),
    ("image,azimuth_deg\nv00.png,0\n./v00.png,40\n", "row 3: image './v00.png' is already"),
    ("image,azimuth_deg\nv00.png,1e300\n", "row 2: azimuth_deg must be in"),
    ("image,azimuth_deg,inplane_deg\nv00.png,0,-1e300\n", "row 2: inplane_deg must be in"),
    ("image,azimuth_deg\n../v00.png,0\n", "row 2: column 'image' names '../v00.png', outside"),
    ("image,azimuth_deg\n/etc/passwd,0\n", "row 2: column 'image' names '/etc/passwd', outside"),
    ("image,azimuth_deg\nsub/../../v00.png,0\n", "outside the training folder"),
    ("image,azimuth_deg,mask\nv00.png,0,../v01.png\n", "row 2: column 'mask' names"),
    ("image,azimuth_deg,box_x,box_y,box_w,box_h\nv00.png,0,1,2,3\n", "row 2: 5 fields for 6"),
    ("image,azimuth_deg\nv00.png,0,9\n", "row 2: more fields"),
    ("image,azimuth_deg\nv00.png,0\x00\n", "row 2: column 'azimuth_deg' must be a number"),
    ('image,azimuth_deg\n"v00.png,0\n', "row 2: 1 fields for 2"),
    ("", "the file is empty"),
    ("image,azimuth_deg\n", "no rows"),
    ("image,azimuth_deg,box_x,box_y,box_w,box_h\nv00.png,0,nan,0,5,5\n", "row 2: column 'box_x'"),
    ("image,azimuth_deg,elevation_deg\nv00.png,0,95\n", "row 2: elevation_deg must be in"),
    ("image,azimuth_deg,box_x,box_y,box_w,box_h\nv00.png,0,500,500,50,50\n", "is not inside"),
    ("image,azimuth_deg\nmissing.png,0\n", "row 2: image file not found"),
    ("image,azimuth_deg\nv00.png,0,\n", "row 2: more fields"),
    ("image,azimuth_deg,instance\nv00.png,0,a\nv01.png,20,\n", "row 3: the instance column"),
])
def test_bad_poses_csv(folder, tmp_path, text, message):
    source = make_csv(folder, tmp_path, text)
    out = tmp_path / "m.npz"
    r = invoke("train", source, "-o", out)
    assert r.exit_code == 1, r.output
    assert message in r.output and ("poses.csv" in r.output or "v00.png" in r.output)
    assert not out.exists()


def test_poses_csv_not_utf8_names_the_file_and_line(folder, tmp_path):
    source = make_csv(folder, tmp_path, b"image,azimuth_deg\nv00.png,0\n" + b"\xff\xfe,1\n")
    r = invoke("train", source, "-o", tmp_path / "m.npz")
    assert r.exit_code == 1 and "poses.csv, line 3: not UTF-8" in r.output


def test_poses_csv_with_a_byte_order_mark_is_read(folder, tmp_path):
    text = (folder / "poses.csv").read_text()
    source = make_csv(folder, tmp_path, b"\xef\xbb\xbf" + text.encode())
    r = invoke("train", source, "-o", tmp_path / "m.npz")
    assert r.exit_code == 0, r.output


def test_outside_paths_when_allowed(folder, tmp_path):
    from posevote.data import read_poses_csv

    source = make_csv(folder, tmp_path, f"image,azimuth_deg\n{folder / 'v00.png'},0\n"
                                        "../set/v01.png,20\n")
    with pytest.raises(ValueError, match="outside the training folder"):
        read_poses_csv(source)
    assert len(read_poses_csv(source, allow_outside_paths=True)) == 2
    r = invoke("train", source, "--allow-outside-paths", "-o", tmp_path / "m.npz")
    assert r.exit_code == 0, r.output


def test_missing_training_folder_and_poses(tmp_path):
    r = invoke("train", tmp_path / "none", "-o", tmp_path / "m.npz")
    assert r.exit_code == 1 and "training folder not found" in r.output
    r = invoke("train", tmp_path, "-o", tmp_path / "m.npz")
    assert r.exit_code == 1 and "poses.csv" in r.output


# --- the API ----------------------------------------------------------------------------

def test_poses_in_degrees_are_refused(synthetic_training):
    images, az, boxes = synthetic_training
    with pytest.raises(ValueError, match="poses: row .* radians"):
        PoseEstimator().fit(images, np.degrees(az), boxes=boxes)


@pytest.mark.parametrize(("poses", "text"), [
    ("abc", "poses must be an array of numbers"),
    ([[0.0, 3.0]] * 18, "elevation"),
    ([np.nan] * 18, "not finite"),
])
def test_bad_poses_arrays(synthetic_training, poses, text):
    images, _, _ = synthetic_training
    with pytest.raises(ValueError, match=text):
        PoseEstimator().fit(images, poses)


def test_bad_fit_arguments(synthetic_training):
    images, az, _ = synthetic_training
    with pytest.raises(TypeError, match="single path"):
        PoseEstimator().fit("some_folder", az)
    with pytest.raises(ValueError, match="boxes must have shape"):
        PoseEstimator().fit(images, az, boxes=np.zeros((3, 4)))
    with pytest.raises(ValueError, match=r"instances\[1\] must be a non-empty string"):
        PoseEstimator().fit(images[:2], az[:2], instances=["a", ""])
    with pytest.raises(TypeError, match=r"images\[0\]: expected an image file path"):
        PoseEstimator().fit([[0, 1]], az[:1])


@pytest.mark.parametrize(("img", "error", "text"), [
    (np.full((64, 64), 200.0), ValueError, "divide a 0..255 image by 255"),
    (np.full((64, 64), -0.5), ValueError, "must lie in"),
    (np.full((64, 64), np.nan), ValueError, "NaN"),
    (np.zeros((64, 64), np.int32), TypeError, "pixel type"),
    (np.zeros((0, 64)), ValueError, "empty"),
    (np.zeros((64, 64, 2)), ValueError, "shape"),
    ([[0.0]], TypeError, "expected an image file path or a numpy array"),
])
def test_bad_test_images(fitted_estimator, img, error, text):
    with pytest.raises(error, match=text):
        fitted_estimator.estimate(img)


def test_float_overshoot_is_clipped(fitted_estimator, draw):
    img = draw(np.radians(100)) * 1.03 - 0.01
    assert fitted_estimator.estimate(img).found


def test_the_caller_says_the_channel_order(fitted_estimator, draw):
    grey = (draw(np.radians(100)) * 255).astype(np.uint8)
    rgb = np.dstack([grey, grey // 2, grey // 4])
    bgr = rgb[..., ::-1].copy()
    a = fitted_estimator.estimate(rgb)
    b = fitted_estimator.estimate(bgr, channels="bgr")
    assert a.best.azimuth == b.best.azimuth and a.best.score == b.best.score
    with pytest.raises(ValueError, match="channels must be one of rgb, bgr"):
        fitted_estimator.estimate(rgb, channels="brg")


def test_api_values(fitted_estimator):
    from posevote.inference.setup import SearchOptions

    with pytest.raises(ValueError, match="SearchOptions.scale_range"):
        SearchOptions(scale_range=(1.0, 1e6))
    with pytest.raises(ValueError, match="SearchOptions.scale_steps"):
        SearchOptions(scale_steps=10**9)
    with pytest.raises(ValueError, match="SearchOptions.scale_range"):
        SearchOptions(scale_range="12")
    with pytest.raises(ValueError, match="min_score must be a finite number"):
        PoseEstimator(min_score=float("nan"))._settings()
    with pytest.raises(ValueError, match="unknown parameter 'nosuch'"):
        PoseEstimator().set_params(nosuch=1)


# --- results folders --------------------------------------------------------------------

def test_a_held_results_folder_is_refused(tiny_protocol, tmp_path):
    from posevote._io import folder_lock
    from posevote.evaluation.runner import run_protocol

    out = tmp_path / "res"
    with folder_lock(out):
        with pytest.raises(ValueError, match=f"{out}: another posevote evaluate .* is writing"):
            run_protocol(tiny_protocol, out, log=lambda m: None)
    run_protocol(tiny_protocol, out, log=lambda m: None)   # free again


def test_double_records_count_once_and_every_is_honoured(tiny_protocol, tmp_path):
    from posevote.evaluation.runner import run_protocol, slug

    out = tmp_path / "res"
    first = run_protocol(tiny_protocol, out, log=lambda m: None)
    assert first["rows"][0]["overall"]["n"] == 4
    records = out / "records" / f"{slug('weights + fitting')}__only.jsonl"
    records.write_text(records.read_text() * 2)     # two runs that overlapped
    again = run_protocol(tiny_protocol, out, log=lambda m: None)
    assert again["rows"][0]["overall"]["n"] == 4
    half = run_protocol(tiny_protocol, out, every=2, log=lambda m: None)
    assert half["every"] == 2 and half["rows"][0]["overall"]["n"] == 2


def test_the_time_of_a_killed_run_counts(tiny_protocol, tmp_path):
    from posevote.evaluation.runner import run_protocol, slug

    out = tmp_path / "res"
    run_protocol(tiny_protocol, out, log=lambda m: None)
    records = out / "records" / f"{slug('weights + fitting')}__only.jsonl"
    records.write_text("".join(records.read_text().splitlines(keepends=True)[:2]))
    # A run killed after 1000 s: it wrote wall.json as it went, not summary.json.
    (out / "wall.json").write_text(json.dumps({"wall_seconds_total": 1000.0}))
    resumed = run_protocol(tiny_protocol, out, log=lambda m: None)
    assert resumed["wall_seconds_total"] > 1000.0
    assert json.loads((out / "wall.json").read_text())["wall_seconds_total"] > 1000.0


def test_stale_temporaries_are_cleaned_and_live_ones_kept(tmp_path):
    from posevote._io import atomic_write_text

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True).stdout.strip()
    stale = tmp_path / f".a.txt.{dead}.x1y2.tmp"
    live = tmp_path / f".a.txt.{os.getppid()}.x1y2.tmp"
    other = tmp_path / ".b.txt.1.zzz.tmp"
    for p in (stale, live, other):
        p.write_text("half")
    atomic_write_text(tmp_path / "a.txt", "whole")
    assert not stale.exists() and live.exists() and other.exists()
    assert (tmp_path / "a.txt").read_text() == "whole"


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_workers_end_with_their_parent(sig):
    if not sys.platform.startswith("linux"):
        pytest.skip("the parent-death signal is Linux's")
    code = ("import time\n"
            "from posevote._parallel import worker_pool\n"
            "pool = worker_pool(2)\n"
            "futures = [pool.submit(time.sleep, 60) for _ in range(2)]\n"
            "time.sleep(0.5)\n"
            "print(*[p.pid for p in pool._processes.values()], flush=True)\n"
            "time.sleep(60)\n")
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        pids = [int(p) for p in parent.stdout.readline().split()]
        assert len(pids) == 2
        parent.send_signal(sig)
        parent.wait(timeout=30)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and any(_running(p) for p in pids):
            time.sleep(0.1)
        assert not any(_running(p) for p in pids)
    finally:
        parent.kill()
        parent.wait()
        parent.stdout.close()


def _running(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().split(") ")[-1][0] != "Z"
    except FileNotFoundError:
        return False


# --- a wrong object -----------------------------------------------------------------------

def test_the_default_preset_rejects_what_is_not_the_object(synthetic_training, tmp_path):
    from posevote.evaluation.synthetic import clutter_background

    images, az, boxes = synthetic_training
    est = PoseEstimator.from_preset("default").fit(images, az, boxes=boxes)
    clutter = clutter_background((128, 128), rng=np.random.default_rng(0))
    result = est.estimate(clutter)
    assert not result.found and result.best is None and 0 < result.top_score < est.min_score
    assert est.set_params(min_score=0.0).estimate(clutter).found   # the threshold decides
    est.set_params(min_score=0.54).save(tmp_path / "m.npz")
    path = tmp_path / "clutter.png"
    cv2.imwrite(str(path), (clutter * 255).astype(np.uint8))
    r = invoke("estimate", tmp_path / "m.npz", path)
    assert r.exit_code == 3 and "below min_score 0.54" in r.output
    r = invoke("estimate", tmp_path / "m.npz", path, "--min-score", "0")
    assert r.exit_code == 0


@pytest.mark.parametrize(("line", "text"), [(2, "leads outside"), (3, "leads outside"),
                                            (2, "does not take")])
def test_epfl_metadata_cannot_lead_outside(epfl_dir, tmp_path, line, text):
    import shutil

    from posevote.data import read_epfl

    copy = tmp_path / "tripod-seq"
    copy.mkdir()
    for name in ("tripod-seq.txt", "times.txt", "bbox_01.txt"):
        shutil.copy(epfl_dir / name, copy / name)
    meta = (copy / "tripod-seq.txt").read_text().splitlines()
    pattern = "../../etc/%02d" + ("_%03d" if line == 2 else "") + ".txt"
    meta[line] = pattern if text == "leads outside" else "x_%d_%d_%d.jpg"
    (copy / "tripod-seq.txt").write_text("\n".join(meta) + "\n")
    with pytest.raises(ValueError, match=text):
        read_epfl(copy, cars=[1])


def test_decoding_in_threads_keeps_stderr(tmp_path, capfd):
    from concurrent.futures import ThreadPoolExecutor

    from posevote.data import read_image

    good = tmp_path / "g.png"
    cv2.imwrite(str(good), _noise())
    bad = tmp_path / "b.jpg"
    _edited_jpeg(bad, lambda b: b[:-2] + b"\0\0\0" + b[-2:])

    def read(path):
        try:
            return read_image(path).shape
        except ValueError as exc:
            return str(exc)

    with ThreadPoolExecutor(8) as pool:
        out = list(pool.map(read, [good, bad] * 50))
    assert out[0::2] == [(64, 64)] * 50 and all("extraneous bytes" in o for o in out[1::2])
    os.write(2, b"still here\n")
    assert "still here" in capfd.readouterr().err


# --- paths that escape, outputs over inputs, degenerate ranges (issue 64) ---------------

def test_a_link_out_of_the_training_folder_is_refused(folder, tmp_path):
    from posevote.data import read_poses_csv

    secret = tmp_path / "secret"
    secret.mkdir()
    cv2.imwrite(str(secret / "s.png"), _noise())
    source = make_csv(folder, tmp_path, "image,azimuth_deg\nv00.png,0\nlinked.png,20\n")
    (source / "linked.png").symlink_to(secret / "s.png")
    r = invoke("train", source, "-o", tmp_path / "m.npz")
    assert r.exit_code == 1 and "row 3" in r.output and "'linked.png'" in r.output
    assert "leads outside the training folder" in r.output and not (tmp_path / "m.npz").exists()
    # A linked folder too; allowed on request.
    (source / "poses.csv").write_text("image,azimuth_deg\nv00.png,0\nsub/s.png,20\n")
    (source / "sub").symlink_to(secret, target_is_directory=True)
    with pytest.raises(ValueError, match="row 3: column 'image' names 'sub/s.png', a link"):
        read_poses_csv(source)
    assert len(read_poses_csv(source, allow_outside_paths=True)) == 2


def test_one_image_under_two_names_is_refused(folder, tmp_path):
    source = make_csv(folder, tmp_path, "image,azimuth_deg\nv01.png,20\nalias.png,200\n")
    (source / "alias.png").symlink_to(source / "v01.png")
    r = invoke("train", source, "-o", tmp_path / "m.npz")
    assert r.exit_code == 1 and "row 3: image 'alias.png' is already given in row 2" in r.output


def test_a_link_inside_the_training_folder_is_read(folder, tmp_path):
    from posevote.data import read_poses_csv

    source = make_csv(folder, tmp_path, "image,azimuth_deg\nv00.png,0\nsame.png,20\n")
    (source / "same.png").symlink_to(source / "v01.png")
    assert len(read_poses_csv(source)) == 2


@pytest.mark.parametrize("name", ["poses.csv", "v00.png", "model"])
def test_train_writes_a_model_file_never_over_an_input(folder, tmp_path, name):
    source = make_csv(folder, tmp_path, (folder / "poses.csv").read_text())
    before = (source / name).read_bytes() if (source / name).exists() else None
    r = invoke("train", source, "-o", source / name)
    assert r.exit_code == 2 and "-o" in r.output and ".npz" in r.output
    assert ((source / name).read_bytes() if before is not None else None) == before


def test_the_overlay_never_replaces_the_image(model, image, tmp_path):
    import shutil

    photo = tmp_path / "photo.png"
    shutil.copy(image, photo)
    before = photo.read_bytes()
    r = invoke("estimate", model, photo, "--overlay", photo)
    assert r.exit_code == 2 and "--overlay" in r.output and "the image itself" in r.output
    assert photo.read_bytes() == before


def test_a_scale_range_of_one_value_searches_one_scale(model, image):
    r = invoke("estimate", model, image, "--scale-range", "1", "1")
    assert r.exit_code in (0, 3) and "Traceback" not in r.output and "Error" not in r.output
    from posevote.inference.setup import SearchOptions

    assert SearchOptions(scale_range=(1.0, 1.0), scale_steps=5).grid()[1].tolist() == [1.0]


def test_a_model_header_nested_too_deep_or_with_a_key_twice(model, tmp_path, image):
    with np.load(model) as data:
        content = {k: data[k] for k in data.files}
    text = bytes(content["header"]).decode()
    for case, header in (("deep", '{"format": ' + "[" * 100_000 + "]" * 100_000 + "}"),
                         ("twice", '{"version": 6, ' + text[1:])):
        content["header"] = np.frombuffer(header.encode(), dtype=np.uint8)
        np.savez(tmp_path / f"{case}.npz", **content)
        r = invoke("estimate", tmp_path / f"{case}.npz", image)
        assert r.exit_code == 1 and f"{case}.npz" in r.output, r.output
        assert ("nests too deep" if case == "deep" else "'version' appears twice") in r.output


def test_a_flipped_bit_in_a_compressed_array_names_the_file(model, tmp_path, image):
    import zipfile

    out = tmp_path / "flipped.npz"
    with zipfile.ZipFile(model) as src:
        info = src.getinfo("xy.npy")
        assert info.compress_type == zipfile.ZIP_DEFLATED
    raw = bytearray(model.read_bytes())
    at = info.header_offset + 30 + len(info.filename) + len(info.extra) + 40
    raw[at] ^= 0x10
    out.write_bytes(bytes(raw))
    with pytest.raises(ValueError, match="flipped.npz"):
        PoseEstimator.load(out)
    r = invoke("estimate", out, image)
    assert r.exit_code == 1 and "flipped.npz" in r.output and "Traceback" not in r.output


def test_the_image_limit_variable_is_checked_where_an_image_is_read(image):
    env = {**os.environ, "POSEVOTE_MAX_IMAGE_PIXELS": "abc"}
    ok = subprocess.run([sys.executable, "-m", "posevote.cli", "presets"], env=env,
                        capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0 and "Traceback" not in ok.stderr
    for value in ("abc", "-1", "inf"):
        env["POSEVOTE_MAX_IMAGE_PIXELS"] = value
        r = subprocess.run([sys.executable, "-c", "from posevote.data import read_image; "
                            f"read_image({str(image)!r})"], env=env, capture_output=True,
                           text=True, timeout=120)
        assert r.returncode == 1 and "POSEVOTE_MAX_IMAGE_PIXELS" in r.stderr
        assert repr(value) in r.stderr


def test_fit_origins_far_out_are_refused(synthetic_training):
    images, az, boxes = synthetic_training
    origins = np.column_stack([boxes[:, 0], boxes[:, 1], np.ones(len(az))])
    origins[2, 0] = 1e300
    with pytest.raises(ValueError, match=r"origins: row 2 is \[1e\+300"):
        PoseEstimator().fit(images, az, boxes=boxes, origins=origins)
    origins[2, 0], origins[3, 2] = 10.0, 1e9
    with pytest.raises(ValueError, match="origins: row 3"):
        PoseEstimator().fit(images, az, boxes=boxes, origins=origins)
