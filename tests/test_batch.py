"""Many images with one model: expansion, order, worker processes, resuming, output."""

from __future__ import annotations

import csv
import io
import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from posevote.batch import CSV_FIELDS, estimate_images, expand_images
from posevote.cli import cli


@pytest.fixture(scope="module")
def model(saved_model):
    return saved_model


@pytest.fixture(scope="module")
def frames(tmp_path_factory, draw):
    folder = tmp_path_factory.mktemp("frames")
    for i, az in enumerate((40, 100, 250)):
        cv2.imwrite(str(folder / f"f{i}.png"), (draw(np.radians(az)) * 255).astype(np.uint8))
    (folder / "notes.txt").write_text("not an image")
    return folder


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_expand_images(frames, tmp_path):
    names = [p.name for p in expand_images([frames])]
    assert names == ["f0.png", "f1.png", "f2.png"]
    assert [p.name for p in expand_images([str(frames / "f[12].png"), frames / "f0.png"])] == [
        "f1.png", "f2.png", "f0.png"]
    with pytest.raises(FileNotFoundError, match="no file matches"):
        expand_images([str(frames / "*.jpg")])
    with pytest.raises(FileNotFoundError, match="image file not found"):
        expand_images([frames / "nope.png"])
    with pytest.raises(ValueError, match="holds no image"):
        expand_images([tmp_path])


def test_json_lines_in_order_and_csv(model, frames):
    r = invoke("estimate", model, frames, "--json")
    assert r.exit_code == 0, r.output
    records = [json.loads(line) for line in r.output.splitlines()]
    assert [rec["image"].rsplit("/", 1)[-1] for rec in records] == ["f0.png", "f1.png", "f2.png"]
    truth = (40, 100, 250)
    for rec, az in zip(records, truth, strict=True):
        assert abs((rec["best"]["azimuth_deg"] - az + 180) % 360 - 180) < 20
    r = invoke("estimate", model, frames, "--csv")
    rows = list(csv.reader(io.StringIO(r.output)))
    assert rows[0] == list(CSV_FIELDS) and len(rows) == 4
    assert float(rows[2][CSV_FIELDS.index("azimuth_deg")]) == pytest.approx(
        records[1]["best"]["azimuth_deg"])


def test_workers_give_the_same_records(model, frames):
    one = list(estimate_images(model, expand_images([frames])))
    two = list(estimate_images(model, expand_images([frames]), jobs=2))
    assert [r["best"] for r in one] == [r["best"] for r in two]


def test_the_results_folder_resumes(model, frames, tmp_path):
    out = tmp_path / "out"
    first = list(estimate_images(model, expand_images([frames]), out=out))
    lines = (out / "estimates.jsonl").read_text().splitlines()
    (out / "estimates.jsonl").write_text(lines[0] + "\n" + lines[1][:20])
    seen, said = [], []
    again = list(estimate_images(model, expand_images([frames]), out=out,
                                 progress=lambda d, t: seen.append(d), log=said.append))
    assert seen[0] == 1 and "resuming: 1 of 3" in said[0]
    assert [r["best"] for r in again] == [r["best"] for r in first]
    rows = list(csv.reader(io.StringIO((out / "estimates.csv").read_text())))
    assert len(rows) == 4
    redone = list(estimate_images(model, expand_images([frames]), out=out,
                                  settings={"max_modes": 1}, log=said.append))
    assert "another model or settings" in said[-1]
    assert all(len(r["modes"]) <= 1 for r in redone)


def test_bad_images_in_a_batch(model, frames, tmp_path):
    bad = tmp_path / "bad.png"
    bad.write_text("not an image")
    r = invoke("estimate", model, frames / "f0.png", bad, frames / "f1.png")
    assert r.exit_code == 1
    assert "bad.png: cannot decode" in r.output and "f1.png: azimuth" in r.output
    # each line says how far to trust it: the probability, and "ambiguous" where it is
    line = next(x for x in r.output.splitlines() if x.startswith(str(frames / "f1.png")))
    p = float(line.split("  p ")[1].split()[0])
    assert 0.0 <= p <= 1.0 and line.endswith("ambiguous") == (p < 0.5)
    assert "1 of 3 images could not be estimated" in r.output


def test_batch_options(model, frames, tmp_path):
    blank = tmp_path / "blank"
    blank.mkdir()
    for i in range(2):
        cv2.imwrite(str(blank / f"b{i}.png"), np.zeros((64, 64), np.uint8))
    r = invoke("estimate", model, blank)
    assert r.exit_code == 3 and "no object found" in r.output
    r = invoke("estimate", model, frames, "--json", "--csv")
    assert r.exit_code == 2 and "--csv" in r.output
    r = invoke("estimate", model, frames, "--overlay", tmp_path / "o.png")
    assert r.exit_code == 2 and "--overlay" in r.output and "3 given" in r.output
    (tmp_path / "cam.json").write_text(json.dumps({"fx": 500, "fy": 500, "cx": 64, "cy": 64}))
    r = invoke("estimate", model, frames, "--json", "--camera", tmp_path / "cam.json",
               "--out", tmp_path / "res")
    assert r.exit_code == 0, r.output
    rec = json.loads(r.output.splitlines()[0])
    assert len(rec["best"]["R_cam_obj"]) == 3 and "t_cam_obj_m" not in rec["best"]
    assert (tmp_path / "res" / "estimates.csv").is_file()


def test_an_image_replaced_since_its_estimate_is_redone(model, frames, tmp_path, draw):
    import shutil

    folder = tmp_path / "frames"
    shutil.copytree(frames, folder)
    out = tmp_path / "out"
    first = list(estimate_images(model, expand_images([folder]), out=out))
    # Another photo under the same name, the others untouched.
    cv2.imwrite(str(folder / "f1.png"), (draw(np.radians(300)) * 255).astype(np.uint8))
    said = []
    again = list(estimate_images(model, expand_images([folder]), out=out, log=said.append))
    assert any("1 image(s) changed" in m and "f1.png" in m for m in said)
    assert again[0]["best"] == first[0]["best"] and again[2]["best"] == first[2]["best"]
    assert again[1]["best"] != first[1]["best"]
    kept = [json.loads(line) for line in (out / "estimates.jsonl").read_text().splitlines()]
    assert sorted(r["image"] for r in kept) == sorted(r["image"] for r in first)
    assert all("stamp" not in r for r in again)
    # Unchanged since: nothing redone.
    said.clear()
    list(estimate_images(model, expand_images([folder]), out=out, log=said.append))
    assert not any("changed" in m for m in said)


def test_csv_on_stdout_quotes_names_with_commas_and_newlines(model, frames, tmp_path):
    import shutil

    odd = tmp_path / "a,b\nc.png"
    shutil.copy(frames / "f0.png", odd)
    r = invoke("estimate", model, odd, frames / "f1.png", "--csv")
    assert r.exit_code == 0, r.output
    rows = list(csv.reader(io.StringIO(r.output)))
    assert len(rows) == 3 and rows[1][0] == str(odd)


def test_folders_are_read_in_natural_order(frames, tmp_path):
    import shutil

    for name in ("obj1__110.png", "obj1__10.png", "obj1__5.png", "obj2__0.png"):
        shutil.copy(frames / "f0.png", tmp_path / name)
    names = [p.name for p in expand_images([tmp_path])]
    assert names == ["obj1__5.png", "obj1__10.png", "obj1__110.png", "obj2__0.png"]
    assert [p.name for p in expand_images([str(tmp_path / "obj1*.png")])] == names[:3]


def test_output_piped_into_head_ends_quietly(model, frames):
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "posevote.cli", "estimate", str(model),
                             str(frames)] + [str(frames / "f0.png")] * 40,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    first = proc.stdout.readline()
    proc.stdout.close()                   # what `head -1` does
    _, err = proc.communicate(timeout=120)
    assert first and b"Broken pipe" not in err and b"Error" not in err and b"Traceback" not in err
