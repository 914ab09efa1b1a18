import json

import cv2
import numpy as np
import pytest

from posevote._io import read_records
from posevote.evaluation.protocols import Row
from posevote.evaluation.runner import pose_error_deg, run_protocol, slug


def test_run_resume_and_report(tiny_protocol, tmp_path):
    out = tmp_path / "res"
    seen = []
    summary = run_protocol(tiny_protocol, out, progress=lambda d, t: seen.append((d, t)),
                           log=lambda m: None)
    assert seen[-1] == (4, 4)
    row = summary["rows"][0]
    assert row["overall"]["n"] == 4 and row["overall"]["median"] < 20
    assert row["overall"]["detection_rate"] == 100.0
    assert row["overall"]["flip_rate"] == 0.0
    assert list(row["splits"]) == ["only"] and row["splits"]["only"]["n"] == 4
    assert set(row["spread"]) >= {"median", "mean", "under_45", "flip_rate"}
    rec = read_records(out / "records" / f"{slug('weights + fitting')}__only.jsonl")[0]
    assert 0.0 <= rec["probability"] <= 1.0 and rec["half_turn"] is False
    assert len(rec["profile"]) >= 2 and all(len(p) == 3 for p in rec["profile"])
    assert summary["rows"][1] == {"name": "later", "available": False, "note": "arrives later"}
    for name in ("summary.json", "results.csv", "report.md", "error_histogram.png",
                 "per_instance.png", "scatter.png", "worst_cases.png"):
        assert (out / name).is_file(), name
    assert "not available: arrives later" in (out / "report.md").read_text()
    assert json.loads((out / "summary.json").read_text())["protocol"] == "tiny"
    assert len((out / "results.csv").read_text().splitlines()) == 5
    # An interrupted run: the last record was cut short. The rerun redoes only it.
    records = out / "records" / f"{slug('weights + fitting')}__only.jsonl"
    lines = records.read_text().splitlines()
    records.write_text("\n".join(lines[:2]) + "\n" + lines[2][:15])
    done = []
    again = run_protocol(tiny_protocol, out, progress=lambda d, t: done.append(d),
                         log=lambda m: None)
    assert done[0] == 2 and done[-1] == 4
    assert len(read_records(records)) == 4
    assert again["rows"][0]["overall"]["n"] == 4


def test_run_rejects_bad_arguments(tiny_protocol, tmp_path):
    with pytest.raises(ValueError, match="unknown row"):
        run_protocol(tiny_protocol, tmp_path, rows=["nope"], log=lambda m: None)
    with pytest.raises(ValueError, match="jobs must be an integer"):
        run_protocol(tiny_protocol, tmp_path, jobs=0, log=lambda m: None)


def test_pose_error_half_turn():
    assert pose_error_deg(np.radians(190), np.radians(10), half_turn=False) == pytest.approx(180)
    assert pose_error_deg(np.radians(190), np.radians(10), half_turn=True) == pytest.approx(0)
    assert pose_error_deg(np.radians(100), np.radians(10), half_turn=True) == pytest.approx(90)


def test_changed_settings_redo_records(tiny_protocol, tmp_path):
    from dataclasses import replace

    out = tmp_path / "res"
    run_protocol(tiny_protocol, out, log=lambda m: None)
    changed = replace(tiny_protocol, rows=(replace(tiny_protocol.rows[0],
                                                   params={"refine__fit": False}),))
    messages, done = [], []
    run_protocol(changed, out, log=messages.append, progress=lambda d, t: done.append(d))
    assert done[0] == 0 and any("changed" in m for m in messages)


def test_records_of_other_code_are_redone(tiny_protocol, tmp_path):
    import json

    from posevote.evaluation.runner import code_fingerprint

    out = tmp_path / "res"
    run_protocol(tiny_protocol, out, log=lambda m: None)
    assert json.loads((out / "code.json").read_text()) == {"fingerprint": code_fingerprint()}
    messages, done = [], []
    run_protocol(tiny_protocol, out, log=messages.append, progress=lambda d, t: done.append(d))
    assert done[0] > 0 and not any("other posevote code" in m for m in messages)
    (out / "code.json").write_text(json.dumps({"fingerprint": "0123456789abcdef"}))
    messages, done = [], []
    before = json.loads((out / "summary.json").read_text())["wall_seconds_total"]
    summary = run_protocol(tiny_protocol, out, log=messages.append,
                           progress=lambda d, t: done.append(d))
    assert done[0] == 0 and any("other posevote code" in m for m in messages)
    # Every record was redone: the earlier runs' time no longer counts.
    assert before > 0
    assert summary["wall_seconds_total"] == summary["wall_seconds_this_run"]


def test_default_rows_and_all(tiny_protocol, tmp_path):
    from dataclasses import replace

    two = replace(tiny_protocol, rows=(tiny_protocol.rows[0],
                                       Row(name="no fitting", params={"refine__fit": False})),
                  default_rows=("no fitting",))
    summary = run_protocol(two, tmp_path / "default", log=lambda m: None)
    assert [r["name"] for r in summary["rows"]] == ["no fitting"]
    summary = run_protocol(two, tmp_path / "all", rows=["all"], log=lambda m: None)
    assert [r["name"] for r in summary["rows"]] == ["weights + fitting", "no fitting"]


def test_processes_give_the_same_records_and_leave_opencv_threads(tiny_protocol, tmp_path):
    # The workers run one thread each (OpenCV's set in the parent before they
    # are forked: set in a forked child it hung); the estimates are the same.
    quiet = {"log": lambda m: None, "rows": ["weights + fitting"]}
    threads = cv2.getNumThreads()
    one = run_protocol(tiny_protocol, tmp_path / "one", **quiet)
    two = run_protocol(tiny_protocol, tmp_path / "two", jobs=2, **quiet)
    assert cv2.getNumThreads() == threads
    key = f"{slug('weights + fitting')}__only.jsonl"
    a, b = (sorted(read_records(tmp_path / d / "records" / key), key=lambda r: r["image"])
            for d in ("one", "two"))
    assert [r["estimate_deg"] for r in a] == [r["estimate_deg"] for r in b]
    assert one["rows"][0]["overall"]["median"] == two["rows"][0]["overall"]["median"]


def test_the_library_prints_nothing(tiny_protocol, tmp_path, capsys):
    run_protocol(tiny_protocol, tmp_path / "quiet")
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == ""
