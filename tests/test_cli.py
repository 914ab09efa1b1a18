import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from posevote.cli import cli


@pytest.fixture(scope="module")
def model_file(training_folder, tmp_path_factory):
    out = tmp_path_factory.mktemp("model") / "model.npz"
    result = CliRunner().invoke(cli, ["train", str(training_folder), "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "18 images" in result.output
    return out


def test_train_threads_give_the_same_model_and_are_not_stored(model_file, training_folder,
                                                              tmp_path):
    from posevote import PoseEstimator

    out = tmp_path / "threads.npz"
    result = CliRunner().invoke(cli, ["train", str(training_folder), "-o", str(out),
                                      "--threads", "2"])
    assert result.exit_code == 0, result.output
    one, two = PoseEstimator.load(model_file), PoseEstimator.load(out)
    assert two.n_jobs == 1
    np.testing.assert_array_equal(one.model_.weight, two.model_.weight)


def test_train_reads_the_origin_columns(training_folder, tmp_path):
    import shutil

    from posevote import PoseEstimator
    from posevote.data import read_poses_csv, write_poses_csv

    folder = tmp_path / "origins"
    shutil.copytree(training_folder, folder)
    ts = read_poses_csv(folder)
    centres = ts.boxes[:, :2] + ts.boxes[:, 2:] / 2
    write_poses_csv(replace(ts, origins=centres + [0.0, 5.0]), folder)
    out = tmp_path / "o.npz"
    result = CliRunner().invoke(cli, ["train", str(folder), "-o", str(out)])
    assert result.exit_code == 0, result.output
    # Five pixels below the box centre (its half-pixel convention aside), in every view.
    np.testing.assert_allclose(PoseEstimator.load(out).model_.view_origin,
                               [[0.5, 5.5]] * len(ts), atol=0.01)


@pytest.fixture
def test_image(tmp_path, draw):
    path = tmp_path / "test.png"
    cv2.imwrite(str(path), (draw(np.radians(100)) * 255).astype(np.uint8))
    return path


def test_estimate_prints_json_and_overlay(model_file, test_image, tmp_path):
    overlay = tmp_path / "overlay.png"
    result = CliRunner().invoke(cli, ["estimate", str(model_file), str(test_image), "--json",
                                      "--overlay", str(overlay)])
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    assert data["found"] and abs(data["best"]["azimuth_deg"] - 100) < 15
    assert overlay.stat().st_size > 1000


def test_estimate_plain_text_and_weights(model_file, test_image, tmp_path):
    runner = CliRunner()
    result = runner.invoke(cli, ["estimate", str(model_file), str(test_image)])
    assert result.exit_code == 0 and result.output.startswith("azimuth")
    threaded = runner.invoke(cli, ["estimate", str(model_file), str(test_image), "--threads", "2"])
    assert threaded.exit_code == 0 and threaded.output == result.output
    result = runner.invoke(cli, ["weights", str(model_file), "-o", str(tmp_path / "w.png")])
    assert result.exit_code == 0 and (tmp_path / "w.png").is_file()


def test_train_and_estimate_say_when_the_object_looks_alike_from_another_side(coil_dir,
                                                                              tmp_path):
    result = CliRunner().invoke(cli, ["train", str(coil_dir), "--layout", "coil", "--objects",
                                      "47", "--azimuth-step-deg", "40",       # a ring
                                      "-o", str(tmp_path / "ring.npz")])
    assert result.exit_code == 0, result.output
    assert "9 of 9 views look alike from another side" in result.output
    result = CliRunner().invoke(cli, ["estimate", str(tmp_path / "ring.npz"),
                                      str(Path(coil_dir) / "obj47__100.png")])
    assert result.exit_code == 0, result.output
    assert "ambiguous: the object looks alike from another side here (lookalike 0.9" \
        in result.output


def test_not_found_exit_code(model_file, tmp_path):
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.zeros((40, 40), np.uint8))
    result = CliRunner().invoke(cli, ["estimate", str(model_file), str(blank)])
    assert result.exit_code == 3


@pytest.mark.parametrize("images", [1, 2])
def test_not_found_says_what_to_try(model_file, test_image, images):
    result = CliRunner().invoke(cli, ["estimate", str(model_file), *[str(test_image)] * images,
                                      "--min-score", "0.999"])
    assert result.exit_code == 3 and "no object found" in result.output
    assert "--scale-range" in result.output and "--min-score 0" in result.output


@pytest.mark.parametrize("kind", ["missing", "corrupt", "foreign"])
def test_bad_model_file(kind, test_image, tmp_path):
    path = tmp_path / "m.npz"
    if kind == "corrupt":
        path.write_bytes(b"PK\x03\x04 broken")
    elif kind == "foreign":
        np.savez(path, x=np.zeros(2))
    result = CliRunner().invoke(cli, ["estimate", str(path), str(test_image)])
    assert result.exit_code == 1
    assert "Error:" in result.output and "m.npz" in result.output


def test_bad_image_and_csv(model_file, training_folder, tmp_path):
    bad = tmp_path / "bad.png"
    bad.write_text("nope")
    result = CliRunner().invoke(cli, ["estimate", str(model_file), str(bad)])
    assert result.exit_code == 1 and "bad.png: cannot decode" in result.output
    folder = tmp_path / "t"
    folder.mkdir()
    (folder / "poses.csv").write_text("image,azimuth_deg\nx.png,nan\n")
    cv2.imwrite(str(folder / "x.png"), np.zeros((8, 8), np.uint8))
    out = tmp_path / "out.npz"
    result = CliRunner().invoke(cli, ["train", str(folder), "-o", str(out)])
    assert result.exit_code == 1 and "row 2" in result.output
    assert not out.exists()


def test_usage_errors(model_file, test_image):
    runner = CliRunner()
    assert runner.invoke(cli, ["estimate", str(model_file), str(test_image), "--bogus"]
                         ).exit_code == 2
    result = runner.invoke(cli, ["estimate", str(model_file), str(test_image), "--threads", "0"])
    assert result.exit_code == 2 and "--threads" in result.output
    result = runner.invoke(cli, ["train", "x", "-o", "y.npz", "--param", "nonsense=1"])
    assert result.exit_code == 2 and "unknown estimator parameter" in result.output
    result = runner.invoke(cli, ["train", "x", "-o", "y.npz", "--layout", "coil"])
    assert result.exit_code == 2 and "--objects" in result.output


def test_installed_command(model_file, test_image):
    exe = Path(sys.executable).parent / "posevote"
    if not exe.exists():
        pytest.skip("the posevote console script is not installed beside this Python")
    proc = subprocess.run([str(exe), "estimate", str(model_file), str(test_image), "--json"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["found"]
    proc = subprocess.run([str(exe), "estimate", str(model_file), "/nonexistent.png"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1 and proc.stderr.startswith("Error:")


def test_demo_runs_end_to_end(tmp_path):
    pytest.importorskip("pybullet")
    result = CliRunner().invoke(cli, ["demo", "-o", str(tmp_path), "--images", "2"])
    assert result.exit_code == 0, result.output
    assert "median" in result.output
    assert (tmp_path / "results.csv").read_text().count("\n") == 3
    assert len(list(tmp_path.glob("test_*.png"))) == 2


def test_evaluate_errors(tmp_path):
    runner = CliRunner()
    result = runner.invoke(cli, ["evaluate", "nonsense", "--data", str(tmp_path)])
    assert result.exit_code == 2
    result = runner.invoke(cli, ["evaluate", "coil-category", "--data", str(tmp_path / "none")])
    assert result.exit_code == 1 and "data folder not found" in result.output
    result = runner.invoke(cli, ["evaluate", "coil-category", "--data", str(tmp_path),
                                 "--out", str(tmp_path / "o")])
    assert result.exit_code == 1 and "no views of object 6" in result.output


def test_evaluate_coil_category_subsample(coil_dir, tmp_path):
    out = tmp_path / "coil"
    result = CliRunner().invoke(cli, ["evaluate", "coil-category", "--data", str(coil_dir.parent),
                                      "--out", str(out), "--every", "80", "--rows", "weights"])
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    row = next(r for r in summary["rows"] if r["name"] == "weights")
    assert summary["every"] == 80 and row["overall"]["n"] > 5
    assert "| weights | cars seen |" in result.output and "HOG + 1-NN" in result.output


def test_train_category_model_with_pruning(synthetic_training, tmp_path):
    images, az, boxes = synthetic_training
    lines = ["image,azimuth_deg,box_x,box_y,box_w,box_h,instance"]
    for i, (img, a, b) in enumerate(zip(images, az, boxes, strict=True)):
        for inst in ("a", "b"):
            cv2.imwrite(str(tmp_path / f"{inst}{i:02d}.png"), (img * 255).astype(np.uint8))
            lines.append(f"{inst}{i:02d}.png,{np.degrees(a):.1f},{b[0]},{b[1]},{b[2]},{b[3]},{inst}")
    (tmp_path / "poses.csv").write_text("\n".join(lines) + "\n")
    out = tmp_path / "cat.npz"
    result = CliRunner().invoke(cli, ["train", str(tmp_path), "-o", str(out), "--prune",
                                      "aggressive"])
    assert result.exit_code == 0, result.output
    assert "2 instance(s)" in result.output and "pruned from" in result.output
    result = CliRunner().invoke(cli, ["estimate", str(out), str(tmp_path / "a03.png"), "--json"])
    assert result.exit_code == 0, result.output
    # The two instances are the same images: a tie, below the default margin
    # (1.05), so the estimate abstains from naming one.
    payload = json.loads(result.output)
    assert payload["instance"] == "" and payload["instance_margin"] == pytest.approx(1.0, abs=0.01)


def test_presets_are_listed_and_trained_from(training_folder, tmp_path):
    runner = CliRunner()
    result = runner.invoke(cli, ["presets"])
    assert result.exit_code == 0, result.output
    for name in ("default", "cluttered", "turntable", "category"):
        assert f"\n{name} " in "\n" + result.output
    assert "chosen on:" in result.output
    verbose = runner.invoke(cli, ["presets", "-v"]).output
    assert "steps: search -> rerank by template -> modes -> fit -> local refinement (profile) " \
        "-> half-turn -> share scale" in verbose
    assert "steps: search -> verify -> modes" in verbose
    out = tmp_path / "m.npz"
    result = runner.invoke(cli, ["train", str(training_folder), "-o", str(out), "--preset",
                                 "cluttered", "--param", "search.scale_steps=5",
                                 "--param", "max_modes=2"])
    assert result.exit_code == 0, result.output
    # No terminal, no bar: what follows the images' features is said all the same.
    assert "learning the views shrunk for image level(s) 1.8" in result.output
    with np.load(out) as data:
        header = json.loads(bytes(data["header"]))
    assert header["preset"]["name"] == "cluttered"
    assert header["preset"]["overrides"]["max_modes"] == 2
    assert header["params"]["search"]["scale_steps"] == 5
    # The preset's level 1.8: the views shrunk by it are in the file.
    assert header["extra"]["levels"] == [1.8] and "level_model_0" in np.load(out).files
    # An extension's group switched on with its defaults, then one of its fields.
    result = runner.invoke(cli, ["train", str(training_folder), "-o", str(out), "--param",
                                 "templates=on", "--param", "templates.half_turn=False"])
    assert result.exit_code == 0, result.output
    with np.load(out) as data:
        header = json.loads(bytes(data["header"]))
    assert header["params"]["templates"] == {"rerank": True, "weigh": True, "half_turn": False}
    assert "view_template" in np.load(out).files


@pytest.mark.parametrize(("args", "message"), [
    (["--preset", "fast"], "unknown preset 'fast'"),
    (["--param", "search.sigma=1"], "unknown estimator parameter 'search.sigma'"),
    (["--param", "search=3"], "set the fields of search one by one"),
    (["--param", "search.rerank=template"], "the template re-ranking is TemplateOptions.rerank"),
    (["--param", "search.scale_steps=0"], "SearchOptions.scale_steps must be an integer"),
    (["--param", "appearance.jitter=0.1"], "appearance is None"),
])
def test_train_refuses_bad_presets_and_params(training_folder, tmp_path, args, message):
    result = CliRunner().invoke(cli, ["train", str(training_folder), "-o",
                                      str(tmp_path / "m.npz"), *args])
    assert result.exit_code in (1, 2) and message in result.output, result.output
    assert not (tmp_path / "m.npz").exists()


def test_written_files_follow_the_umask(model_file, test_image, tmp_path):
    import os
    import stat

    old = os.umask(0o022)
    try:
        from posevote import PoseEstimator

        out = tmp_path / "m.npz"
        PoseEstimator.load(model_file).save(out)
        assert stat.S_IMODE(out.stat().st_mode) == 0o644
        os.chmod(out, 0o640)
        PoseEstimator.load(model_file).save(out)   # an overwritten file keeps its mode
        assert stat.S_IMODE(out.stat().st_mode) == 0o640
        overlay = tmp_path / "o.png"
        result = CliRunner().invoke(cli, ["estimate", str(model_file), str(test_image),
                                          "--overlay", str(overlay)])
        assert result.exit_code == 0 and stat.S_IMODE(overlay.stat().st_mode) == 0o644
    finally:
        os.umask(old)


def test_the_first_run_says_it_prepares_its_kernels(monkeypatch, tmp_path, model_file,
                                                    test_image):
    import posevote.cli as cli_module

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "empty"))
    assert not cli_module._kernels_compiled()
    result = CliRunner().invoke(cli, ["estimate", str(model_file), str(test_image)])
    assert result.exit_code == 0 and "preparing posevote's compiled kernels" in result.output
    (tmp_path / "empty" / "x").mkdir(parents=True)
    (tmp_path / "empty" / "x" / "voting._search_kernel-1.py311.nbi").write_bytes(b"")
    assert cli_module._kernels_compiled()
    result = CliRunner().invoke(cli, ["estimate", str(model_file), str(test_image)])
    assert result.exit_code == 0 and "preparing" not in result.output


def test_the_first_runs_kernel_count_ends_before_the_result(monkeypatch, tmp_path):
    from numba.core import event

    import posevote.cli as cli_module

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "empty"))
    before = len(event._registered.get("numba:compile", ()))
    cli_module._first_run_notice()
    assert len(event._registered["numba:compile"]) == before + 1
    cli_module._first_run_done()
    assert len(event._registered.get("numba:compile", ())) == before
    assert cli_module._FIRST_RUN_DONE == []
