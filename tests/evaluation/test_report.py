"""The report: the Markdown table, the CSV of records, and the rows' settings."""

from __future__ import annotations

import csv

from posevote.evaluation.protocols import Protocol, Row
from posevote.evaluation.report import RECORD_FIELDS, markdown_table, write_csv, write_report

_METRICS = {"n": 2, "median": 1.5, "mean": 2.0, "p90": 3.0, "under_22_5": 100.0,
            "under_45": 100.0, "detection_rate": None, "recognition_rate": None,
            "median_seconds": 0.01}


def _summary():
    return {"protocol": "toy", "every": 1, "rows": [
        {"name": "paper", "available": True, "overall": _METRICS, "groups": {"g": _METRICS}},
        {"name": "later", "available": False, "note": "needs data"},
        {"name": "unrun", "available": True}]}


def test_markdown_table_has_every_row():
    table = markdown_table(_summary())
    assert "| paper | all | 2 | 1.50 | 2.00 |" in table and "| paper | g |" in table
    assert "not available: needs data" in table and "| unrun | – | not run |" in table


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
