"""The report: the Markdown table, the CSV of records, and the rows' settings."""

from __future__ import annotations

import csv

from posevote.evaluation.protocols import Protocol, Row
from posevote.evaluation.report import (
    RECORD_FIELDS,
    markdown_table,
    split_table,
    write_csv,
    write_report,
)

_METRICS = {"n": 2, "median": 1.5, "mean": 2.0, "p90": 3.0, "under_22_5": 100.0,
            "under_45": 100.0, "flip_rate": 12.5, "detection_rate": None,
            "recognition_rate": None, "median_seconds": 0.01}


def _summary():
    return {"protocol": "toy", "every": 1, "rows": [
        {"name": "paper", "available": True, "overall": _METRICS, "groups": {"g": _METRICS}},
        {"name": "later", "available": False, "note": "needs data"},
        {"name": "unrun", "available": True}]}


def test_markdown_table_has_every_row():
    table = markdown_table(_summary())
    assert "| paper | all | 2 | 1.50 | 2.00 |" in table and "| paper | g |" in table
    assert "not available: needs data" in table and "| unrun | – | not run |" in table
    assert "| flip % |" in table and "| 100.0 | 12.5 |" in table


def test_split_table_gives_each_fold_and_the_spread():
    summary = _summary()
    assert split_table(summary) == ""          # one split or none: no table
    other = {**_METRICS, "median": 3.5, "flip_rate": 2.5}
    summary["rows"][0]["splits"] = {"fold1": _METRICS, "fold2": other}
    summary["rows"][0]["spread"] = {"median": {"min": 1.5, "max": 3.5, "std": 1.0},
                                    "flip_rate": {"min": 2.5, "max": 12.5, "std": 5.0}}
    table = split_table(summary)
    assert "| paper | fold1 | 2 | 1.50 |" in table and "| paper | fold2 | 2 | 3.50 |" in table
    assert "spread over 2 splits" in table and "1.50-3.50 (sd 1.00)" in table
    assert "2.5-12.5 (sd 5.0)" in table


def test_csv_and_report_say_what_each_row_runs(tmp_path):
    records = [{"row": "paper", "image": "a.png", "error_deg": 1.0, "extra": "dropped"}]
    write_csv(records, tmp_path / "r.csv")
    with (tmp_path / "r.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == list(RECORD_FIELDS) and rows[0]["image"] == "a.png"
    proto = Protocol(name="toy", description="A toy.", splits=(), preset="cluttered",
                     rows=(Row(name="paper", params={"appearance": None}),
                           Row(name="later", params=None, note="needs data")))
    write_report(proto, _summary(), [], tmp_path)
    text = (tmp_path / "report.md").read_text()
    assert "starts from the `cluttered` preset" in text
    assert "- **paper**: `appearance=None`" in text and "- **later**: not available" in text
    assert "steps: search → rerank by template → modes → fit → local refinement (profile)" \
        in text
