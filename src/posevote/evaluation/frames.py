"""The frames benchmark: development COIL objects found, or not, in camera-sized cluttered frames.

Each development object's instance model (a preset, trained on its views every
20 degrees) looks for it in frames of :data:`FRAME_SIZES`: a mosaic of EPFL cars
1-10 frames (real photographs, :func:`mosaic`), with the object's view between
training views pasted at :data:`SCALE_RANGE` times its training size, in-plane
within 30 degrees, 20% hidden behind a patch of another mosaic; and, in as many
frames again, the mosaic alone, which the model of the object whose turn it is
looks at. Every frame is estimated without a threshold, and the preset's own
threshold is applied afterwards, so that every threshold can be read from the
records. An object is found when its frame's detection score (``top_score``:
the best mode's contrast where the preset measures it, else its score) is
above the threshold and
its box overlaps the pasted one by IoU 0.5 or more; an empty frame is a false
alarm when its detection score is above it; a pose is right when it is found and
within 30 degrees of azimuth (on the half circle for the boxes and flat bottles).

Reported per frame size and over both: detection average precision (every
frame's best mode a detection, ranked by detection score), recall and false alarms per
empty frame at the threshold, the azimuth errors of the objects found, the
calibration of the best mode's probability (expected calibration error,
reliability diagram) and its risk-coverage curve, seconds per frame.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from posevote._io import atomic_write_text
from posevote._parallel import ordered_map
from posevote.batch import run_image
from posevote.data.images import read_image
from posevote.data.training_set import read_coil
from posevote.estimator import PoseEstimator
from posevote.evaluation.metrics import (
    accuracy_at_coverage,
    average_precision,
    box_iou,
    calibration,
)
from posevote.evaluation.synthetic import paste_on_clutter
from posevote.geometry import angular_error
from posevote.results import LOOKALIKE

#: The frame sizes, (height, width) pixels: a VGA and a 720p camera.
FRAME_SIZES: tuple[tuple[int, int], ...] = ((480, 640), (720, 1280))
#: The object's size in a frame, relative to its training views (log-uniform).
SCALE_RANGE = (0.4, 3.0)
#: The development objects of ../shared/data (the other COIL objects are held out).
DEVELOPMENT_OBJECTS = (1, 6, 7, 8, 13, 15, 22, 23, 24, 25, 26, 31, 33, 41, 46, 47, 50, 54, 55, 56,
                       57, 58, 60, 61, 64, 68, 71, 72, 73, 74, 76, 79, 83, 85, 86, 91, 92, 96, 97,
                       100)
#: Boxes and flat bottles: their azimuth is scored on the half circle.
HALF_TURN = frozenset({1, 31, 46, 54, 79, 96, 13, 22, 33, 64})
#: A pose is right within this azimuth error (and a found box).
RIGHT_DEG = 30.0
#: The object's size bands (times its training size) the report breaks the frames into.
SIZE_BANDS = (SCALE_RANGE[0], 0.55, 0.7, 1.0, 1.4, 2.0, SCALE_RANGE[1])
#: EPFL cars whose frames make the mosaics (the development cars; 11-20 are held out).
MOSAIC_CARS = tuple(range(1, 11))


@dataclass(frozen=True, kw_only=True)
class FramesSetup:
    """What one run of the benchmark trains and tests.

    Attributes
    ----------
    preset : str
        The preset the objects' models start from.
    params : mapping
        Estimator settings over the preset (``set_params`` keys).
    objects : tuple of int
        COIL objects, each with a model of its own.
    frames : int
        Frames with the object, per object and frame size.
    empty : int
        Frames without an object, per object (its model) and frame size.
    sizes : tuple of (int, int)
        Frame sizes (height, width).
    seed : int
        Frame ``k`` of an object is drawn from ``[seed, object, size, k, kind]``.
    """

    preset: str = "cluttered"
    params: Mapping[str, Any] = field(default_factory=dict)
    objects: tuple[int, ...] = DEVELOPMENT_OBJECTS
    frames: int = 2
    empty: int = 1
    sizes: tuple[tuple[int, int], ...] = FRAME_SIZES
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.objects or not all(isinstance(o, int) and 1 <= o <= 100
                                        for o in self.objects):
            raise ValueError(f"objects must be COIL object numbers, got {self.objects!r}")
        for name in ("frames", "empty"):
            value = getattr(self, name)
            if not (isinstance(value, int) and 0 <= value <= 1000):
                raise ValueError(f"{name} must be an integer in [0, 1000], got {value!r}")
        if not self.sizes or not all(len(s) == 2 and 64 <= min(s) and max(s) <= 4096
                                     for s in self.sizes):
            raise ValueError(f"sizes must be (height, width) pairs of 64-4096 pixels, "
                             f"got {self.sizes!r}")
        if not (isinstance(self.seed, int) and 0 <= self.seed < 2**31):
            raise ValueError(f"seed must be a non-negative integer, got {self.seed!r}")

    def threshold(self) -> float:
        """The preset's (and the settings') ``min_score``: what "found" means by default."""
        return float(PoseEstimator.from_preset(self.preset, **dict(self.params)).min_score)

    def items(self) -> list[dict[str, Any]]:
        """Every frame to estimate: its object, kind, size and index."""
        out = []
        for obj in self.objects:
            for size in self.sizes:
                out += [{"object": obj, "kind": "object", "size": list(size), "index": k}
                        for k in range(self.frames)]
                out += [{"object": obj, "kind": "empty", "size": list(size), "index": k}
                        for k in range(self.empty)]
        return out


@cache
def _mosaic_frames(folder: str) -> tuple[str, ...]:
    from posevote.data.training_set import read_epfl

    return tuple(str(p) for p in read_epfl(folder, cars=list(MOSAIC_CARS)).images)


def mosaic(shape: tuple[int, int], *, rng: np.random.Generator,
           frames: Sequence[str | NDArray[np.float64]]) -> NDArray[np.float64]:
    """A grey canvas of ``shape`` tiled with random crops of real photographs.

    Rows of random heights are filled with tiles of random frames (image
    paths, or grey images in [0, 1]), each scaled by 1 to 2 and mirrored at
    random, cropped to fit: the clutter of real scenes (showrooms, people,
    cars) at the frame's size.
    """
    h, w = shape
    canvas = np.zeros((h, w), dtype=np.float64)
    top = 0
    while top < h:
        row = min(h - top, int(rng.integers(120, 360)))
        left = 0
        while left < w:
            pick = frames[int(rng.integers(len(frames)))]
            tile = read_image(pick) if isinstance(pick, str) else pick
            zoom = float(rng.uniform(1.0, 2.0))
            tile = np.asarray(cv2.resize(tile, None, fx=zoom, fy=zoom,
                                         interpolation=cv2.INTER_LINEAR), dtype=np.float64)
            if rng.random() < 0.5:
                tile = tile[:, ::-1]
            width = min(w - left, int(rng.integers(160, 480)), int(tile.shape[1]))
            rows = min(row, tile.shape[0])
            r0 = int(rng.integers(0, tile.shape[0] - rows + 1))
            c0 = int(rng.integers(0, tile.shape[1] - width + 1))
            canvas[top:top + rows, left:left + width] = tile[r0:r0 + rows, c0:c0 + width]
            left += width
        top += row
    return canvas


def frame(item: dict[str, Any], setup: FramesSetup, data: str
          ) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """The frame of ``item`` (:meth:`FramesSetup.items`) and its truth, drawn from its seed."""
    obj, size = int(item["object"]), (int(item["size"][0]), int(item["size"][1]))
    kind = 0 if item["kind"] == "object" else 1
    rng = np.random.default_rng([setup.seed, obj, size[1], int(item["index"]), kind])
    folder = str(Path(data))
    frames = _mosaic_frames(_epfl_folder(folder))

    def backdrop(shape: tuple[int, int], *, rng: np.random.Generator) -> NDArray[np.float64]:
        return mosaic(shape, rng=rng, frames=frames)

    if item["kind"] == "empty":
        return backdrop(size, rng=rng), {}
    azimuth = int(rng.choice([a for a in range(0, 360, 5) if a % 20]))
    view = read_coil(_coil_folder(folder), objects=[obj], azimuths_deg=[azimuth])
    scale = float(np.exp(rng.uniform(*np.log(SCALE_RANGE))))
    pasted = paste_on_clutter(view.load_images()[0], view.boxes[0], rng=rng, canvas_shape=size,
                              scale_range=(scale, scale), backdrop=backdrop)
    return pasted.image, {"truth_deg": float(azimuth), "scale": scale,
                          "truth_box": list(pasted.box), "inplane_deg":
                          float(np.degrees(pasted.inplane))}


def _coil_folder(data: str) -> str:
    from posevote.evaluation.protocols import _find

    return str(_find(Path(data), "coil-100"))


def _epfl_folder(data: str) -> str:
    from posevote.evaluation.protocols import _epfl_folder as epfl

    return str(epfl(data))


def frame_record(est: PoseEstimator, item: dict[str, Any]) -> dict[str, Any]:
    """Make, estimate and score one frame (in a worker, through
    :func:`posevote.batch.run_image`); ``item`` carries the setup and the data folder."""
    setup, data = item["setup"], item["data"]
    image, truth = frame(item, setup, data)
    start = time.perf_counter()
    result = est.estimate(image)
    seconds = time.perf_counter() - start
    rec: dict[str, Any] = {k: item[k] for k in ("object", "kind", "size", "index")}
    rec.update(truth, seconds=seconds, score=result.top_score, probability=None, iou=0.0,
               error_deg=None, object_likeness=_object_likeness(est))
    best = result.best
    if best is not None:
        rec.update(probability=best.probability, ambiguous=result.ambiguous,
                   estimate_deg=best.azimuth_deg,
                   box=list(best.box), scale_estimate=best.scale, pose_score=best.score,
                   detection=best.detection_score)
        if truth:
            period = math.pi if item["object"] in HALF_TURN else 2.0 * math.pi
            rec["iou"] = float(box_iou(best.box, truth["truth_box"]))
            rec["error_deg"] = float(np.degrees(angular_error(
                best.azimuth, np.radians(truth["truth_deg"]), period=period)))
    return rec


def _object_likeness(est: PoseEstimator) -> float | None:
    """The median over the model's views of how alike each is to another side
    (``PoseModel.view_lookalike``); None for a model without it."""
    likeness = est.model_.view_lookalike
    if likeness is None or np.isnan(likeness).all():
        return None
    return float(np.nanmedian(likeness))


def _alike_objects(records: Sequence[dict[str, Any]]) -> list[int]:
    """The objects whose views look alike from other sides (median likeness at least
    :data:`posevote.results.LOOKALIKE`): their azimuth is undefined, as the COIL instance
    protocol reports them apart."""
    return sorted({r["object"] for r in records
                   if (r.get("object_likeness") or 0.0) >= LOOKALIKE})


def _found(record: dict[str, Any], threshold: float) -> bool:
    """An object frame whose score is over ``threshold`` and whose box is on the object."""
    return record["score"] > threshold and record["iou"] >= 0.5


def _score(records: Sequence[dict[str, Any]], threshold: float) -> dict[str, Any]:
    """The benchmark's figures over some records, at ``threshold``."""
    objects = [r for r in records if r["kind"] == "object"]
    empties = [r for r in records if r["kind"] == "empty"]
    hit = [r["kind"] == "object" and r["iou"] >= 0.5 for r in records]
    found = [r for r in objects if _found(r, threshold)]
    errors = np.array([r["error_deg"] for r in found], dtype=float)
    right, prob = reported_outcomes(records, threshold)
    cal = calibration(prob, right)
    return {
        "frames": len(objects), "empty_frames": len(empties),
        "average_precision": 100 * average_precision([r["score"] for r in records], hit,
                                                     len(objects)),
        "recall": 100 * len(found) / max(len(objects), 1),
        "false_alarms_per_empty": sum(r["score"] > threshold for r in empties)
        / max(len(empties), 1),
        "found_median_deg": float(np.median(errors)) if errors.size else None,
        "found_within_30": _within(found),
        "ece": cal["ece"], "right_of_p90": _right_above(prob, right, 0.9),
        "accuracy_at_85": 100 * accuracy_at_coverage(prob, right, 0.85),
        "seconds_median": float(np.median([r["seconds"] for r in records])),
    }


def reported_outcomes(records: Sequence[dict[str, Any]], threshold: float
                      ) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """Whether each frame's reported pose is right, and its reported probability.

    What a user sees at ``threshold``: a frame whose best score is not above
    it reports no object (probability 0, never right); otherwise its best
    mode is right when the box is found (IoU >= 0.5) within 30° of azimuth.
    """
    over = np.array([r["score"] > threshold for r in records], dtype=bool)
    right = over & np.array([r["kind"] == "object" and r["iou"] >= 0.5
                             and (r["error_deg"] or 0.0) < RIGHT_DEG for r in records])
    prob = np.where(over, [r["probability"] or 0.0 for r in records], 0.0)
    return right, prob


def _right_above(prob: NDArray[np.float64], right: NDArray[np.bool_], level: float
                 ) -> float | None:
    """The share right of the estimates whose probability is at least ``level``."""
    sel = prob >= level
    return 100 * float(np.mean(right[sel])) if sel.any() else None


def _band(records: Sequence[dict[str, Any]], threshold: float) -> dict[str, Any]:
    """Of some object frames: how many, the share with the best box on the object (IoU >=
    0.5, whatever its score), found, and found within 30 degrees."""
    found = [r for r in records if _found(r, threshold)]
    n = max(len(records), 1)
    return {"frames": len(records), "boxed": 100 * sum(r["iou"] >= 0.5 for r in records) / n,
            "found": 100 * len(found) / n,
            "right": 100 * sum(r["error_deg"] < RIGHT_DEG for r in found) / n}


def summarize(records: Sequence[dict[str, Any]], threshold: float) -> dict[str, Any]:
    """The figures per frame size and over every frame, at ``threshold``; the object frames
    by the object's size (:data:`SIZE_BANDS`, both frame sizes), and the objects whose
    found pose was off by :data:`RIGHT_DEG` or more, and those found and ``ambiguous`` (one
    entry a frame), with the share within :data:`RIGHT_DEG` of the other found."""
    sizes = sorted({tuple(r["size"]) for r in records})
    out = {f"{w}x{h}": _score([r for r in records if tuple(r["size"]) == (h, w)], threshold)
           for h, w in sizes}
    out["all"] = _score(records, threshold)
    objects = [r for r in records if r["kind"] == "object"]
    bands = {f"{lo:g}-{hi:g}": _band([r for r in objects if lo <= r["scale"] < hi
                                      or (hi == SIZE_BANDS[-1] and r["scale"] == hi)],
                                     threshold)
             for lo, hi in zip(SIZE_BANDS[:-1], SIZE_BANDS[1:], strict=True)}
    found = [r for r in objects if _found(r, threshold)]
    wrong = sorted(r["object"] for r in found if r["error_deg"] >= RIGHT_DEG)
    told = [r for r in found if not r.get("ambiguous")]
    alike = _alike_objects(records)
    defined = [r for r in found if r["object"] not in alike]
    return {"threshold": threshold, "by_size": out, "by_object_size": bands,
            "wrong_found": wrong,
            "ambiguous_found": sorted(r["object"] for r in found if r.get("ambiguous")),
            "unambiguous_within_30": _within(told), "alike_objects": alike,
            "defined_within_30": _within(defined)}


def _within(found: Sequence[dict[str, Any]]) -> float | None:
    """The share (%) of some found frames within :data:`RIGHT_DEG` of azimuth."""
    return 100 * float(np.mean([r["error_deg"] < RIGHT_DEG for r in found])) if found else None


_COLUMNS = (("frames", "frames", "{}"), ("empty_frames", "empty", "{}"),
            ("average_precision", "AP %", "{:.1f}"), ("recall", "found %", "{:.1f}"),
            ("false_alarms_per_empty", "false alarms / empty", "{:.2f}"),
            ("found_median_deg", "found: median °", "{:.2f}"),
            ("found_within_30", "found: % < 30°", "{:.1f}"), ("ece", "ECE", "{:.3f}"),
            ("right_of_p90", "% right of p ≥ 0.9", "{:.1f}"),
            ("accuracy_at_85", "% right, top 85%", "{:.1f}"),
            ("seconds_median", "s / frame", "{:.2f}"))


def _objects(objects: Sequence[int]) -> str:
    """Objects listed once each, their frames' count in brackets where over one."""
    return ", ".join(f"{o}" + (f" ({objects.count(o)})" if objects.count(o) > 1 else "")
                     for o in dict.fromkeys(objects)) or "none"


def report_text(setup: FramesSetup, summary: dict[str, Any]) -> str:
    """The report in words (markdown)."""
    from posevote.evaluation.report import row_steps

    def cell(value: Any, fmt: str) -> str:
        return "–" if value is None or (isinstance(value, float) and math.isnan(value)) \
            else fmt.format(value)

    head = "| frames | " + " | ".join(c[1] for c in _COLUMNS) + " |\n"
    head += "|---" * (len(_COLUMNS) + 1) + "|\n"
    rows = "".join(f"| {name} | " + " | ".join(cell(figures[k], f) for k, _, f in _COLUMNS)
                   + " |\n" for name, figures in summary["by_size"].items())
    sizes = ", ".join(f"{w}×{h}" for h, w in setup.sizes)
    wrong = summary["wrong_found"]
    by_band = ("The object frames by the object's size (times its training size; both frame "
               "sizes): how many, the share whose best box is on the object (IoU ≥ 0.5, "
               "whatever its score), found, and right.\n\n"
               "| size | frames | box on the object % | found % | right % |\n"
               "|---|---|---|---|---|\n" + "".join(
                   f"| {name}× | {b['frames']} | {b['boxed']:.1f} | {b['found']:.1f} | "
                   f"{b['right']:.1f} |\n" for name, b in summary["by_object_size"].items())
               + f"\nFound {RIGHT_DEG:g}° or more off (object, frames): " + _objects(wrong)
               + ".\n"
               + "Found and ambiguous (a likely wrong mode, or a view alike to another side: "
               + "the azimuth not to be trusted): " + _objects(summary["ambiguous_found"])
               + "; of the other found, " + cell(summary["unambiguous_within_30"], "{:.1f}")
               + f"% within {RIGHT_DEG:g}°.\n"
               + "Objects whose views look alike from other sides (median likeness ≥ "
               + f"{LOOKALIKE:g}: the azimuth undefined, reported apart as in the COIL instance "
               + "protocol): " + _objects(summary.get("alike_objects", []))
               + "; of the found on the other objects, "
               + cell(summary.get("defined_within_30"), "{:.1f}") + f"% within {RIGHT_DEG:g}°.\n")
    return (f"# frames: {setup.preset} preset\n\n"
            f"{len(setup.objects)} development COIL objects, each its own model (views every "
            f"20° trained); per object and frame size ({sizes}) {setup.frames} frame(s) with "
            f"the object (a view between training views at {SCALE_RANGE[0]:g}-"
            f"{SCALE_RANGE[1]:g}× its training size, in-plane ±30°, 20% hidden) and "
            f"{setup.empty} without, on mosaics of EPFL cars 1-10 frames; seed {setup.seed}; "
            f"overrides {dict(setup.params) or 'none'}. Found: detection score (the "
            "contrast, where the preset measures it) over the threshold "
            f"({summary['threshold']:g}, the preset's) and box IoU ≥ 0.5; right: found and "
            f"within {RIGHT_DEG:g}° of azimuth. The probabilities (ECE, p ≥ 0.9, the most "
            "confident 85%, the plot) are those reported: a frame not found reports p 0.\n\n"
            f"Steps: {row_steps(setup.preset, dict(setup.params))}.\n\n{head}{rows}\n"
            f"{by_band}\n![calibration](calibration.png)\n")


def run_frames(setup: FramesSetup, data: str | Path, out: str | Path, *, jobs: int = 1,
               scheduler: Any = None, progress: Callable[[int, int], None] | None = None,
               log: Callable[[str], None] = lambda _m: None) -> dict[str, Any]:
    """Train every object's model, estimate every frame, write the report in ``out``.

    Parameters
    ----------
    setup : FramesSetup
    data : path
        The folder holding ``coil-100`` and ``epfl-gims08``.
    out : path
        Results folder (created): ``models/``, ``records.jsonl``, ``summary.json``,
        ``report.md``, ``calibration.png``.
    jobs, scheduler, progress, log
        As in :func:`posevote.evaluation.sphere.run_sphere`.

    Returns
    -------
    dict
        The summary (:func:`summarize`), with the wall time.
    """
    from posevote.evaluation.report import plot_calibration

    out, data = Path(out), str(data)
    (out / "models").mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    log(f"training {len(setup.objects)} models ({setup.preset} preset)")
    models = {}
    for obj in setup.objects:
        train = read_coil(_coil_folder(data), objects=[obj], azimuths_deg=range(0, 360, 20))
        path = out / "models" / f"obj{obj}.npz"
        est = PoseEstimator.from_preset(setup.preset, **{**dict(setup.params), "min_score": 0.0})
        est.fit(train.load_images(), train.poses, boxes=train.boxes).save(path)
        models[obj] = str(path)
    items = setup.items()
    jobs_list: list[tuple[Any, ...]] = [
        (frame_record, models[i["object"]], {}, {**i, "setup": setup, "data": data})
        for i in items]
    records = []
    if progress is not None:
        progress(0, len(items))
    for rec in ordered_map(run_image, jobs_list, jobs=jobs, scheduler=scheduler):
        records.append(rec)
        if progress is not None:
            progress(len(records), len(items))
    summary = summarize(records, setup.threshold())
    summary.update(wall_seconds=time.perf_counter() - start, jobs=jobs, preset=setup.preset,
                   params=dict(setup.params), seed=setup.seed)
    atomic_write_text(out / "records.jsonl", "".join(json.dumps(r) + "\n" for r in records))
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2, default=str) + "\n")
    atomic_write_text(out / "report.md", report_text(setup, summary))
    right, prob = reported_outcomes(records, setup.threshold())
    plot_calibration(prob.tolist(), right.tolist(), out / "calibration.png",
                     title=f"frames, {setup.preset} preset: the best mode's probability")
    return summary
