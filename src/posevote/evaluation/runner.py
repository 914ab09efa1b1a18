"""Run an evaluation protocol: train, estimate every test image, score, report.

Layout of a results folder (``--out``)::

    code.json                     fingerprint of the posevote code that made the records
    .lock                         held while a run writes (a second run at once is refused)
    models/<row>__<split>.npz     trained models (reused when their settings match)
    records/<row>__<split>.jsonl  one JSON line per finished test image
    results.csv                   every record of every row (written at the end)
    summary.json                  the metrics of every row, group and split
    report.md                     the table beside the published numbers
    wall.json                     wall time of the runs so far (updated as each run goes)
    *.png                         plots (see :mod:`posevote.evaluation.report`)

Resuming: records are appended one line at a time, flushed and synced, so
an interrupted run keeps what it finished; a new run with the same
``--out`` skips the images already recorded (a last line cut short by the
interruption is ignored and redone). Records and models made by other
posevote code (another version, or edited sources: ``code.json`` holds a
hash of the package's source files) are discarded and redone, so a folder
never mixes the results of two versions. ``results.csv``, ``summary.json`` and
the plots are written atomically, from the records, once every image is
done.

The protocols measure the pose of an object that is in every test image, so
their estimators reject nothing (``min_score=0``, whatever the preset says).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import shutil
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from posevote._io import atomic_write_text, folder_lock, read_records, repair_records
from posevote._parallel import ordered_map
from posevote.batch import run_image
from posevote.estimator import PoseEstimator
from posevote.evaluation.metrics import (
    accuracy_at_coverage,
    box_iou,
    calibration,
    confidence_outcomes,
    flip_threshold_deg,
    summarize_errors,
)
from posevote.evaluation.protocols import Protocol, Row, Split
from posevote.evaluation.report import write_report
from posevote.geometry import angular_error
from posevote.model.pruning import resolve_preset


def slug(text: str) -> str:
    """A file-name-safe form of a row or split name."""
    return re.sub(r"[^A-Za-z0-9]+", "-", text).strip("-").lower()


def pose_error_deg(estimate: float, truth: float, *, half_turn: bool) -> float:
    """Absolute azimuth error in degrees; on the half circle for symmetric objects."""
    err = math.degrees(float(angular_error(estimate, truth)))
    return min(err, 180.0 - err) if half_turn else err


# --- the worker side ------------------------------------------------------------------

def estimate_record(est: PoseEstimator, task: dict[str, Any]) -> dict[str, Any]:
    """Estimate one test image and score it (in a worker process, through
    :func:`posevote.batch.run_image`).

    Parameters
    ----------
    est : PoseEstimator
        The row's model.
    task : dict
        ``image``, ``instance``, ``group``, ``truth`` (radians), ``box``
        (true box or None), ``half_turn``, ``row``, ``split``, ``seen_instance``.

    Returns
    -------
    dict
        The record (fields :data:`RECORD_FIELDS`).
    """
    start = time.perf_counter()
    result = est.estimate(task["image"])
    seconds = time.perf_counter() - start
    rec: dict[str, Any] = {k: task[k] for k in ("row", "split", "image", "instance", "group",
                                                 "seen_instance", "half_turn")}
    truth_box = task["box"]
    rec["truth_deg"] = math.degrees(task["truth"]) % 360.0
    rec.update(dict(zip(("truth_box_x", "truth_box_y", "truth_box_w", "truth_box_h"),
                        truth_box if truth_box is not None else [None] * 4, strict=True)))
    rec["found"] = result.found
    rec["seconds"] = seconds
    best = result.best
    if best is None:
        rec.update(estimate_deg=None, error_deg=180.0 if not task["half_turn"] else 90.0,
                   score=0.0, iou=0.0, detected=False)
        return rec
    rec.update(estimate_deg=best.azimuth_deg,
               error_deg=pose_error_deg(best.azimuth, task["truth"], half_turn=task["half_turn"]),
               score=best.score, inplane_deg=best.inplane_deg, scale=best.scale,
               u=best.position[0], v=best.position[1],
               box_x=best.box[0], box_y=best.box[1], box_w=best.box[2], box_h=best.box[3],
               recognised=result.instance,
               instance_margin=None if math.isnan(result.instance_margin)
               else result.instance_margin)
    rec["probability"] = best.probability
    if len(result.modes) > 1:
        rec.update(second_deg=result.modes[1].azimuth_deg, second_score=result.modes[1].score,
                   second_probability=result.modes[1].probability)
    # The score profile over viewpoints, to calibrate the mode probabilities on
    # (benchmarks/calibrate_modes.py).
    rec["profile"] = [[round(math.degrees(a), 2), round(math.degrees(e), 2), round(v, 5)]
                      for a, e, v in result.viewpoint_scores]
    if truth_box is not None and all(np.isfinite(truth_box)):
        iou = float(box_iou(best.box, truth_box))
        rec.update(iou=iou, detected=iou >= 0.5)
    return rec


# --- the driver side ------------------------------------------------------------------

def code_fingerprint() -> str:
    """Hash of the posevote package's source files (names and contents)."""
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def _check_code(out: Path, log: Callable[[str], None]) -> None:
    """Discard models and records that other posevote code made (see the module docstring)."""
    marker = out / "code.json"
    current = code_fingerprint()
    try:
        previous = json.loads(marker.read_text()).get("fingerprint")
    except (OSError, ValueError, AttributeError):
        previous = None
    stale = [d for d in (out / "models", out / "records") if d.is_dir() and any(d.iterdir())]
    if previous != current and stale:
        log(f"{out}: made by other posevote code (fingerprint {previous} here, {current} "
            "now): its models and records are redone")
        for d in stale:
            shutil.rmtree(d)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(marker, json.dumps({"fingerprint": current}) + "\n")


def _train(protocol: Protocol, row: Row, split: Split, path: Path, records: Path,
           log: Callable[[str], None]) -> dict[str, Any]:
    """Train (or reuse) the model of a row on a split; returns its facts.

    A model file whose settings differ from the row's is retrained, and the
    records made with it are discarded.
    """
    # The protocols measure the pose of an object known to be in the image: no
    # rejection (benchmarks/rejection_threshold.py measures that).
    est = PoseEstimator.from_preset(protocol.preset, **{"min_score": 0.0, **(row.params or {})})
    wanted = est.get_params(deep=False)
    pruning = resolve_preset(est.prune)
    if path.is_file():
        try:
            old = PoseEstimator.load(path)
            if old.get_params(deep=False) == wanted and old.pruning_ == (
                    None if pruning is None else vars(pruning)):
                return _model_facts(old, float("nan"))
        except (OSError, ValueError):
            pass
        if records.is_file():
            log(f"settings of {row.name!r} on {split.name} changed: its records are redone")
            records.unlink()
    log(f"training {row.name!r} on {split.name} ({len(split.train.images)} images)")
    start = time.perf_counter()
    ts = split.train
    est.fit(ts.images, ts.poses, boxes=ts.boxes, instances=list(ts.instances) or None,
            category=ts.category)
    seconds = time.perf_counter() - start
    est.save(path)
    return _model_facts(est, seconds)


def _model_facts(est: PoseEstimator, seconds: float) -> dict[str, Any]:
    return {"train_seconds": seconds, "features": est.model_.n_features,
            "features_full": est.full_model_.n_features,
            "features_kept_percent": 100.0 * est.model_.n_features
            / max(est.full_model_.n_features, 1)}


def run_protocol(protocol: Protocol, out_dir: str | Path, *, jobs: int = 1, every: int = 1,
                 rows: Sequence[str] | None = None,
                 progress: Callable[[int, int], Any] | None = None,
                 log: Callable[[str], None] | None = None, scheduler: Any = None
                 ) -> dict[str, Any]:
    """Run (or resume) a protocol and write its results folder.

    Parameters
    ----------
    protocol : Protocol
        From :func:`posevote.evaluation.protocols.load_protocol`.
    out_dir : str or Path
        Results folder (created; see the module docstring for its layout).
    jobs : int, optional
        Worker processes for the test images (each uses one core).
    every : int, optional
        Test only every ``every``-th image of each split (1: all). A
        subsample is recorded as such in the summary.
    rows : sequence of str, optional
        Only these rows (by name; ``["all"]``: every row); default the
        protocol's ``default_rows``, or all of them if it names none.
    progress : callable, optional
        Called as ``progress(done, total)`` after each test image.
    log : callable, optional
        Receives one-line messages (the library prints nothing itself).
    scheduler : distributed.Client or str, optional
        Estimate the test images on this Dask cluster instead of ``jobs``
        local processes (:mod:`posevote._parallel`); the same records.

    Returns
    -------
    dict
        The summary (also written to ``summary.json``), with
        ``wall_seconds_this_run`` (training included) and
        ``wall_seconds_total`` (summed over the runs that built the folder).
    """
    log = log if log is not None else (lambda message: None)
    for name, value in (("jobs", jobs), ("every", every)):
        if not (isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= 100_000):
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    run_start = time.perf_counter()
    out = Path(out_dir)
    chosen = list(protocol.rows)
    if rows is None and protocol.default_rows:
        rows = protocol.default_rows
    if rows is not None and list(rows) != ["all"]:
        names = {r.name for r in protocol.rows}
        unknown = [r for r in rows if r not in names]
        if unknown:
            raise ValueError(f"unknown row(s) {unknown}; rows of {protocol.name}: "
                             f"{', '.join(sorted(names))}")
        chosen = [r for r in protocol.rows if r.name in rows]
    with folder_lock(out):
        return _run_locked(protocol, out, chosen, jobs=jobs, every=every, progress=progress,
                           log=log, run_start=run_start, scheduler=scheduler)


def _previous_wall(out: Path) -> float:
    """The wall time of the earlier runs that built ``out``, seconds (0 if none is recorded)."""
    for name in ("wall.json", "summary.json"):
        try:
            value = float(json.loads((out / name).read_text()).get("wall_seconds_total", 0.0))
        except (ValueError, OSError, AttributeError, TypeError):
            continue
        if math.isfinite(value) and value >= 0:
            return value
    return 0.0


def _run_locked(protocol: Protocol, out: Path, chosen: list[Row], *, jobs: int, every: int,
                progress: Callable[[int, int], Any] | None, log: Callable[[str], None],
                run_start: float, scheduler: Any) -> dict[str, Any]:
    """:func:`run_protocol` once the folder is held."""
    previous = _previous_wall(out)
    _check_code(out, log)
    (out / "models").mkdir(parents=True, exist_ok=True)
    (out / "records").mkdir(parents=True, exist_ok=True)

    def keep_time() -> None:
        # Written as the run goes, so that a killed run's time still counts.
        atomic_write_text(out / "wall.json", json.dumps(
            {"wall_seconds_total": previous + time.perf_counter() - run_start}) + "\n")

    runnable = [r for r in chosen if r.params is not None]
    facts: dict[str, dict[str, Any]] = {}
    plan: list[tuple[str, Path, list[dict[str, Any]]]] = []
    planned: dict[str, set[str]] = {}
    total = done = 0
    for row in runnable:
        for split in protocol.splits:
            key = f"{slug(row.name)}__{slug(split.name)}"
            model_path = out / "models" / f"{key}.npz"
            record_path = out / "records" / f"{key}.jsonl"
            facts[key] = _train(protocol, row, split, model_path, record_path, log)
            keep_time()
            repair_records(record_path)
            finished = {r["image"] for r in read_records(record_path)}
            tasks = []
            trained = set(split.train.instances)
            planned[key] = set()
            for i in range(0, len(split.test.images), every):
                box = None if split.test.boxes is None else split.test.boxes[i].tolist()
                task = {"row": row.name, "split": split.name, "image": str(split.test.images[i]),
                        "instance": split.test.instances[i], "group": split.groups[i],
                        "seen_instance": split.test.instances[i] in trained,
                        "truth": float(split.test.poses[i, 0]), "box": box,
                        "half_turn": split.half_turn}
                total += 1
                planned[key].add(task["image"])
                if task["image"] in finished:
                    done += 1
                else:
                    tasks.append(task)
            plan.append((str(model_path), record_path, tasks))
    resumed = done
    if done:
        log(f"resuming: {done} of {total} test images already done")
    if progress is not None:
        progress(done, total)
    for model_file, record_path, tasks in plan:
        if not tasks:
            continue
        results = ordered_map(run_image, [(estimate_record, model_file, {}, t) for t in tasks],
                              jobs=jobs, scheduler=scheduler)
        with record_path.open("a", encoding="utf-8") as fh:
            for rec in results:
                fh.write(json.dumps(rec) + "\n")
                fh.flush()
                os.fsync(fh.fileno())
                done += 1
                keep_time()
                if progress is not None:
                    progress(done, total)
    records = []
    for key, images in planned.items():
        # Only this run's selection (--every): a folder may hold more from earlier runs.
        records += [r for r in read_records(out / "records" / f"{key}.jsonl")
                    if r["image"] in images]
    summary = summarize(protocol, chosen, records, facts, every=every)
    summary["wall_seconds_this_run"] = time.perf_counter() - run_start
    # The time of earlier runs counts only when this one resumed their records.
    summary["wall_seconds_total"] = (previous if resumed else 0.0) \
        + summary["wall_seconds_this_run"]
    summary["jobs"] = jobs
    write_report(protocol, summary, records, out)
    atomic_write_text(out / "wall.json", json.dumps(
        {"wall_seconds_total": summary["wall_seconds_total"]}) + "\n")
    return summary


def summarize(protocol: Protocol, rows: Sequence[Row], records: Sequence[dict[str, Any]],
              facts: dict[str, dict[str, Any]], *, every: int = 1) -> dict[str, Any]:
    """Metrics of every row, overall and per group.

    Returns
    -------
    dict
        ``protocol``, ``every`` and ``rows``: one entry per row with
        ``available``, ``note``, ``overall`` and ``groups`` (each: the error
        summary of :func:`posevote.evaluation.metrics.summarize_errors`,
        ``detection_rate`` (percent, when boxes are known),
        ``recognition_rate`` (percent of the views of trained instances whose
        recognised instance is the true one), ``median_seconds``), the same
        per split (``splits``) with their ``spread`` (min, max and standard
        deviation over the splits of each figure), and the models' facts
        (training time, features kept).
    """
    out_rows = []
    for row in rows:
        entry: dict[str, Any] = {"name": row.name, "available": row.params is not None,
                                 "note": row.note}
        mine = [r for r in records if r["row"] == row.name]
        if row.params is not None and mine:
            entry["overall"] = _metrics(mine)
            entry["groups"] = {g: _metrics([r for r in mine if r["group"] == g])
                               for g in sorted({r["group"] for r in mine})}
            entry["instances"] = {n: _metrics([r for r in mine if r["instance"] == n])
                                  for n in sorted({r["instance"] for r in mine})}
            entry["splits"] = {s.name: _metrics([r for r in mine if r["split"] == s.name])
                               for s in protocol.splits
                               if any(r["split"] == s.name for r in mine)}
            entry["spread"] = _spread(entry["splits"].values())
            entry["models"] = {k: v for k, v in facts.items()
                               if k.startswith(slug(row.name) + "__")}
            kept = [v["features_kept_percent"] for v in entry["models"].values()]
            entry["features_kept_percent"] = float(np.mean(kept)) if kept else None
        out_rows.append(entry)
    return {"protocol": protocol.name, "description": protocol.description, "every": every,
            "rows": out_rows}


_SPREAD_KEYS = ("median", "mean", "under_45", "flip_rate", "detection_rate")


def _spread(per_split: Iterable[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Min, max and standard deviation over the splits (the folds) of each headline figure."""
    parts = list(per_split)
    out = {}
    for key in _SPREAD_KEYS:
        vals = np.array([m[key] for m in parts if m.get(key) is not None], dtype=float)
        if vals.size:
            out[key] = {"min": float(vals.min()), "max": float(vals.max()),
                        "std": float(vals.std())}
    return out


def _metrics(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    m: dict[str, Any] = summarize_errors(
        [r["error_deg"] for r in records],
        flip_deg=[flip_threshold_deg(bool(r.get("half_turn", False))) for r in records])
    prob, near, right = confidence_outcomes(records)
    m["ece"] = calibration(prob, near)["ece"]
    m["right_top_85"] = 100.0 * accuracy_at_coverage(prob, right, 0.85)
    det = [r["detected"] for r in records if r.get("detected") is not None]
    m["detection_rate"] = float(100.0 * np.mean(det)) if det else None
    rec = [r.get("recognised") == r["instance"] for r in records
           if r.get("instance_margin") is not None and r.get("seen_instance", True)]
    m["recognition_rate"] = float(100.0 * np.mean(rec)) if rec else None
    m["median_seconds"] = float(np.median([r["seconds"] for r in records]))
    return m
