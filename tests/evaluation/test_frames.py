"""The frames benchmark: frames drawn from their seed, a run end to end, its figures."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from posevote.cli import cli
from posevote.evaluation.frames import (
    FramesSetup,
    frame,
    mosaic,
    report_text,
    reported_outcomes,
    run_frames,
    summarize,
)
from posevote.presets import get_preset


def test_setup_refuses_what_it_cannot_run():
    for bad in ({"objects": ()}, {"frames": -1}, {"sizes": ((10, 10),)}, {"seed": -2}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            FramesSetup(**bad)


def test_a_mosaic_fills_its_canvas_from_its_seed(epfl_dir):
    from posevote.data import read_epfl

    frames = [str(p) for p in read_epfl(epfl_dir, cars=[1]).images[:10]]
    a = mosaic((300, 500), rng=np.random.default_rng(4), frames=frames)
    b = mosaic((300, 500), rng=np.random.default_rng(4), frames=frames)
    assert a.shape == (300, 500) and np.array_equal(a, b)
    assert (a > 0).mean() > 0.95 and a.std() > 0.05       # no gap left, real texture


def test_a_mosaic_of_the_bundled_photographs_has_no_gap():
    from posevote.evaluation.synthetic import bundled_photographs

    photos = bundled_photographs()
    assert len(photos) > 5 and all(p.ndim == 2 and 0.0 <= p.min() <= p.max() <= 1.0
                                   for p in photos)
    a = mosaic((480, 640), rng=np.random.default_rng(1), frames=photos)
    assert a.shape == (480, 640) and (a > 0).mean() > 0.9 and a.std() > 0.05


def test_a_frame_is_drawn_from_its_item(coil_dir):
    data = str(coil_dir.parent)
    setup = FramesSetup(objects=(6,), sizes=((240, 320),))
    item = {"object": 6, "kind": "object", "size": [240, 320], "index": 1}
    one, truth = frame(item, setup, data)
    two, again = frame(item, setup, data)
    assert np.array_equal(one, two) and truth == again
    assert 0.4 <= truth["scale"] <= 3.0 and truth["truth_deg"] % 20 != 0
    empty, nothing = frame({**item, "kind": "empty"}, setup, data)
    assert empty.shape == (240, 320) and nothing == {}


def test_a_run_reports_detection_calibration_and_time(coil_dir, tmp_path):
    setup = FramesSetup(objects=(6,), frames=2, empty=1, sizes=((240, 320),))
    summary = run_frames(setup, coil_dir.parent, tmp_path, jobs=1)
    for name in ("records.jsonl", "summary.json", "report.md", "calibration.png",
                 "models/obj6.npz"):
        assert (tmp_path / name).stat().st_size > 0
    records = [json.loads(line) for line in (tmp_path / "records.jsonl").read_text().splitlines()]
    assert [r["kind"] for r in records] == ["object", "object", "empty"]
    figures = summary["by_size"]["320x240"]
    assert figures["frames"] == 2 and figures["empty_frames"] == 1
    # Estimated without a threshold, judged at the preset's.
    threshold = get_preset("cluttered").params["min_score"]
    assert summary["threshold"] == threshold > 0.0
    assert figures["false_alarms_per_empty"] == float(records[2]["score"] > threshold)
    assert "Steps: search → rerank by template" in (tmp_path / "report.md").read_text()
    # Each frame carries how alike its model's views are to other sides.
    assert all(0.0 <= r["object_likeness"] <= 1.0 for r in records)


def test_the_figures_at_a_threshold():
    recs = [{"kind": "object", "object": 6, "size": [480, 640], "scale": 1.0, "score": 0.5,
             "iou": 0.8, "error_deg": 10.0, "probability": 0.9, "seconds": 1.0},
            {"kind": "object", "object": 6, "size": [480, 640], "scale": 1.0, "score": 0.2,
             "iou": 0.1, "error_deg": 90.0, "probability": 0.6, "seconds": 1.0},
            {"kind": "empty", "size": [480, 640], "score": 0.3, "iou": 0.0, "error_deg": None,
             "probability": 0.8, "seconds": 1.0}]
    at = summarize(recs, 0.25)["by_size"]["640x480"]
    assert at["recall"] == 50.0 and at["false_alarms_per_empty"] == 1.0
    assert at["average_precision"] == pytest.approx(50.0)
    assert at["found_within_30"] == 100.0 and at["right_of_p90"] == 100.0
    assert summarize(recs, 0.4)["by_size"]["640x480"]["false_alarms_per_empty"] == 0.0
    # What is reported: under the threshold no pose (p 0, not right).
    right, prob = reported_outcomes(recs, 0.25)
    assert right.tolist() == [True, False, False] and prob.tolist() == [0.9, 0.0, 0.8]
    assert at["ece"] == pytest.approx((0.1 + 0.8) / 3)


def test_the_object_frames_by_size_and_the_wrong_poses_found():
    def rec(scale, score, iou, error, obj=1):
        return {"kind": "object", "object": obj, "size": [480, 640], "scale": scale,
                "score": score, "iou": iou, "error_deg": error, "probability": 0.5,
                "seconds": 1.0}

    recs = [rec(0.45, 0.5, 0.8, 10.0), rec(0.5, 0.1, 0.8, 10.0), rec(0.5, 0.5, 0.2, 10.0),
            rec(1.2, 0.5, 0.9, 50.0, obj=47), rec(3.0, 0.5, 0.9, 5.0),
            {"kind": "empty", "size": [480, 640], "score": 0.9, "iou": 0.0,
             "error_deg": None, "probability": 0.5, "seconds": 1.0}]
    summary = summarize(recs, 0.25)
    small = summary["by_object_size"]["0.4-0.55"]
    assert small == {"frames": 3, "boxed": pytest.approx(200 / 3),
                     "found": pytest.approx(100 / 3), "right": pytest.approx(100 / 3)}
    assert summary["by_object_size"]["1-1.4"] == {"frames": 1, "boxed": 100.0,
                                                  "found": 100.0, "right": 0.0}
    assert summary["by_object_size"]["2-3"]["frames"] == 1      # the top size counts
    assert summary["wrong_found"] == [47]
    text = report_text(FramesSetup(), summary)
    assert "| 0.4-0.55× | 3 | 66.7 | 33.3 | 33.3 |" in text
    assert "Found 30° or more off (object, frames): 47." in text
    assert summary["ambiguous_found"] == [] and summary["unambiguous_within_30"] == pytest.approx(200 / 3)
    # The ring said its azimuth was not to be trusted: apart, the other found are all right.
    recs[3]["ambiguous"] = True
    summary = summarize(recs, 0.25)
    assert summary["ambiguous_found"] == [47] and summary["unambiguous_within_30"] == 100.0
    assert "ambiguous (a likely wrong mode" in report_text(FramesSetup(), summary)
    assert ": 47; of the other found, 100.0% within 30°." in report_text(FramesSetup(), summary)


def test_the_objects_alike_from_every_side_are_reported_apart():
    def rec(obj, error, likeness):
        return {"kind": "object", "object": obj, "size": [480, 640], "scale": 1.0,
                "score": 0.5, "iou": 0.9, "error_deg": error, "probability": 0.5,
                "seconds": 1.0, "object_likeness": likeness}

    # The ring (0.93 alike) is off by a half-turn, the box (0.4) right; a model of an
    # earlier posevote (no likeness) counts with the others.
    recs = [rec(47, 170.0, 0.93), rec(47, 10.0, 0.93), rec(6, 5.0, 0.4), rec(8, 50.0, None)]
    summary = summarize(recs, 0.25)
    assert summary["alike_objects"] == [47]
    assert summary["defined_within_30"] == 50.0
    assert summary["by_size"]["640x480"]["found_within_30"] == 50.0
    assert ("(median likeness ≥ 0.8: the azimuth undefined, reported apart as in the COIL "
            "instance protocol): 47; of the found on the other objects, 50.0% within 30°."
            ) in report_text(FramesSetup(), summary)
    recs[0]["object_likeness"] = recs[1]["object_likeness"] = 0.79
    assert summarize(recs, 0.25)["alike_objects"] == []


def test_the_command_line_runs_the_frames(monkeypatch, tmp_path, coil_dir):
    from posevote.evaluation import frames

    small = {"objects": (6,), "frames": 1, "empty": 1, "sizes": ((240, 320),)}
    monkeypatch.setattr(frames, "FramesSetup",
                        lambda **kw: FramesSetup(**{**kw, **small}))
    r = CliRunner().invoke(cli, ["evaluate", "frames", "--data", str(coil_dir.parent),
                                 "--out", str(tmp_path / "f")])
    assert r.exit_code == 0, r.output
    assert "| 320x240 |" in r.output
    bad = CliRunner().invoke(cli, ["evaluate", "coil-loio", "--preset", "default"])
    assert bad.exit_code == 2 and "only for frames" in bad.output
