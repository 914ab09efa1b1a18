"""Estimating many images with one model: in order, in worker processes, resumable.

:func:`estimate_images` yields one record per image (``{"image": ..., **PoseEstimate.to_dict()}``),
in the order given, whatever the number of workers. With an output folder
the records are appended to ``estimates.jsonl`` one line at a time (flushed
and synced), so a killed run keeps what it finished and a rerun on the same
folder skips those images (unless an image file changed since: its size or
modification time, recorded with its estimate); ``estimates.csv`` (one row per image, the best
mode) is written atomically at the end. ``batch.json`` holds what the
records were made with (the model file's hash and the settings): records
made with another model or other settings are discarded and redone.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import re
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from posevote._io import atomic_write_text, folder_lock, read_records, repair_records
from posevote._parallel import ordered_map

#: Image suffixes taken from a folder.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".pgm", ".ppm")
#: The most images one batch may name.
MAX_IMAGES = 1_000_000
CSV_FIELDS = ("image", "object", "found", "azimuth_deg", "elevation_deg", "inplane_deg", "scale", "u", "v",
              "box_x", "box_y", "box_w", "box_h", "score", "contrast", "probability", "lookalike",
              "ambiguous",
              "top_score", "instance",
              *(f"R{i}{j}" for i in range(3) for j in range(3)), "tx_m", "ty_m", "tz_m",
              "seconds")


def natural_key(path: Path) -> tuple[Any, ...]:
    """A path's sort key with its runs of digits read as numbers: ``__5`` before ``__10``
    before ``__110``, as a file browser shows them."""
    parts = re.split(r"(\d+)", str(path))
    return tuple((0, int(p), p) if p.isdigit() else (1, p, p) for p in parts)


def expand_images(items: Sequence[str | Path]) -> list[Path]:
    """Image files from paths, folders (their images, in natural order) and glob patterns.

    Raises
    ------
    FileNotFoundError
        If an item matches no file.
    ValueError
        If the items name no image, or more than :data:`MAX_IMAGES`.
    """
    import glob

    out: list[Path] = []
    for item in items:
        path = Path(item)
        if path.is_dir():
            found = sorted((p for p in path.iterdir()
                            if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES),
                           key=natural_key)
            if not found:
                raise ValueError(f"{path}: the folder holds no image ({', '.join(IMAGE_SUFFIXES)})")
            out.extend(found)
        elif path.is_file():
            out.append(path)
        elif glob.has_magic(str(item)):
            matched = sorted((Path(p) for p in glob.glob(str(item)) if Path(p).is_file()),
                             key=natural_key)
            if not matched:
                raise FileNotFoundError(f"{item}: no file matches this pattern")
            out.extend(matched)
        else:
            raise FileNotFoundError(f"image file not found: {path}")
        if len(out) > MAX_IMAGES:
            raise ValueError(f"more than {MAX_IMAGES:,} images in one batch")
    return out


_ESTIMATOR: dict[str, Any] = {}


def run_image(work: Callable[[Any, Any], dict[str, Any]], model: str,
              settings: dict[str, Any], item: Any) -> dict[str, Any]:
    """One image's record: ``work(estimator, item)`` with the estimator of a model file and
    settings (:meth:`~posevote.PoseEstimator.set_params` changes).

    The one per-image runner: a batch's images (:func:`estimate_images`), a
    protocol's test images (:mod:`posevote.evaluation.runner`) and the rendered
    sphere's (:mod:`posevote.evaluation.sphere`) are each ``work`` run here, in
    a worker process (:func:`posevote._parallel.ordered_map`), where the
    estimator is loaded once and kept for the next image of the same model and
    settings. ``work`` must be a module-level function (it is pickled by name).
    """
    from posevote.estimator import PoseEstimator

    key = json.dumps([model, settings], sort_keys=True, default=str)
    est = _ESTIMATOR.get(key)
    if est is None:
        _ESTIMATOR.clear()
        est = _ESTIMATOR[key] = PoseEstimator.load(model).set_params(**settings)
    return work(est, item)


def estimate_record(est: Any, item: tuple[dict[str, float] | None, str, int]) -> dict[str, Any]:
    """One image's record in a batch: ``item`` is (camera, image, max_objects).

    With ``max_objects`` over 1 the record holds ``objects``, one
    :meth:`~posevote.PoseEstimate.to_dict` per object found
    (:meth:`~posevote.PoseEstimator.estimate_objects`). A bad image gives a
    record with ``error`` instead of stopping the batch.
    """
    from posevote.camera import Camera

    camera, image, max_objects = item
    cam = None if camera is None else Camera.from_dict(camera, where="camera")
    try:
        if max_objects > 1:
            found = est.estimate_objects(image, max_objects, camera=cam)
            return {"image": image, "found": bool(found),
                    "objects": [r.to_dict() for r in found]}
        result = est.estimate(image, camera=cam)
    except (OSError, ValueError, TypeError, MemoryError) as exc:
        return {"image": image, "found": False, "error": str(exc)}
    return {"image": image, **result.to_dict()}


def object_records(record: dict[str, Any]) -> list[dict[str, Any]]:
    """One record per object of an image's record (``object``: 0, 1, ...; one if none found)."""
    if "objects" not in record:
        return [{"image": record["image"], "object": 0,
                 **{k: v for k, v in record.items() if k != "image"}}]
    if not record["objects"]:
        return [{"image": record["image"], "object": 0, "found": False,
                 **({"error": record["error"]} if "error" in record else {})}]
    return [{"image": record["image"], "object": k, **obj}
            for k, obj in enumerate(record["objects"])]


def csv_row(record: dict[str, Any]) -> list[Any]:
    """The :data:`CSV_FIELDS` of one object's record (its best mode; :func:`object_records`)."""
    best = record.get("best") or {}
    R = best.get("R_cam_obj") or [[None] * 3] * 3
    t = best.get("t_cam_obj_m") or [None] * 3
    pos = best.get("position_px") or [None, None]
    box = best.get("box_px") or [None] * 4
    return [record["image"], record.get("object", 0), record.get("found", False),
            best.get("azimuth_deg"),
            best.get("elevation_deg"), best.get("inplane_deg"), best.get("scale"), *pos, *box,
            best.get("score"), best.get("contrast"), best.get("probability"),
            best.get("lookalike"), record.get("ambiguous"),
            record.get("top_score"), record.get("instance"),
            *(R[i][j] for i in range(3) for j in range(3)), *t, record.get("seconds")]


def _fingerprint(model: Path, settings: dict[str, Any], camera: dict[str, Any] | None) -> str:
    digest = hashlib.sha256(model.read_bytes())
    digest.update(json.dumps([settings, camera], sort_keys=True, default=str).encode())
    return digest.hexdigest()[:16]


def estimate_images(model: str | Path, images: Sequence[Path], *,
                    settings: dict[str, Any] | None = None,
                    camera: dict[str, Any] | None = None, jobs: int = 1,
                    max_objects: int = 1, out: str | Path | None = None,
                    progress: Callable[[int, int], None] | None = None,
                    log: Callable[[str], None] | None = None,
                    scheduler: Any = None) -> Iterator[dict[str, Any]]:
    """Estimate every image; yields the records in the order of ``images``.

    Parameters
    ----------
    model : str or Path
        Model file.
    images : sequence of Path
        From :func:`expand_images`.
    settings : dict, optional
        :meth:`~posevote.PoseEstimator.set_params` changes.
    camera : dict, optional
        The test camera's ``fx, fy, cx, cy`` (and ``dist``: :meth:`posevote.camera.Camera.to_dict`).
    jobs : int, optional
        Worker processes.
    max_objects : int, optional
        Objects to find per image (:func:`estimate_record`).
    out : str or Path, optional
        Results folder (see the module docstring); a rerun resumes it.
    progress : callable, optional
        Called as ``progress(done, total)``.
    log : callable, optional
        Receives one-line messages.
    scheduler : distributed.Client or str, optional
        Estimate on this Dask cluster instead of ``jobs`` local processes.

    Examples
    --------
    >>> import tempfile, cv2
    >>> from posevote import PoseEstimator
    >>> from posevote.data import toy_views
    >>> folder = Path(tempfile.mkdtemp())
    >>> images, poses, boxes = toy_views(range(0, 360, 20))
    >>> PoseEstimator().fit(images, poses, boxes=boxes).save(folder / "toy.npz")
    >>> _ = cv2.imwrite(str(folder / "50.png"), (255 * toy_views([50])[0][0]).astype("uint8"))
    >>> records = estimate_images(folder / "toy.npz", [folder / "50.png"], out=folder / "out")
    >>> [(Path(r["image"]).name, round(r["best"]["azimuth_deg"])) for r in records]
    [('50.png', 52)]
    >>> sorted(p.name for p in (folder / "out").iterdir())
    ['.lock', 'batch.json', 'estimates.csv', 'estimates.jsonl']
    """
    log = log if log is not None else (lambda message: None)
    settings = dict(settings or {})
    model = Path(model)
    names = [str(p) for p in images]
    if out is None:
        yield from _run(str(model), settings, camera, max_objects, names, jobs, {}, None,
                        progress, scheduler)
        return
    folder = Path(out)
    with folder_lock(folder):
        marker, records_path = folder / "batch.json", folder / "estimates.jsonl"
        current = _fingerprint(model, {**settings, "max_objects": max_objects}, camera)
        try:
            previous = json.loads(marker.read_text()).get("fingerprint")
        except (OSError, ValueError, AttributeError):
            previous = None
        if previous != current and records_path.is_file():
            log(f"{folder}: its estimates were made with another model or settings: redone")
            records_path.unlink()
        atomic_write_text(marker, json.dumps({"fingerprint": current, "model": str(model)}) + "\n")
        repair_records(records_path)
        stamps = {n: _stamp(n) for n in names}
        kept = read_records(records_path)
        changed = [r["image"] for r in kept
                   if r["image"] in stamps and r.get("stamp") != stamps[r["image"]]]
        if changed:
            log(f"{len(changed)} image(s) changed since their estimate (first: {changed[0]}): "
                "redone")
            kept = [r for r in kept if r["image"] not in set(changed)]
            atomic_write_text(records_path, "".join(json.dumps(r) + "\n" for r in kept))
        done = {r["image"]: {k: v for k, v in r.items() if k != "stamp"} for r in kept}
        if done:
            log(f"resuming: {sum(n in done for n in names)} of {len(names)} images already done")
        with records_path.open("a", encoding="utf-8") as fh:
            yield from _run(str(model), settings, camera, max_objects, names, jobs, done, fh,
                            progress, scheduler, stamps)
        text = io.StringIO()
        writer = csv.writer(text, lineterminator="\n")
        writer.writerow(CSV_FIELDS)
        final = {r["image"]: r for r in read_records(records_path)}
        writer.writerows(csv_row(o) for n in names if n in final for o in object_records(final[n]))
        atomic_write_text(folder / "estimates.csv", text.getvalue())


def _stamp(name: str) -> str:
    """What tells a file's content changed without reading it: its size and modification time."""
    try:
        st = os.stat(name)
    except OSError:
        return ""
    return f"{st.st_size}:{st.st_mtime_ns}"


def _run(model: str, settings: dict[str, Any], camera: dict[str, Any] | None,
         max_objects: int, names: list[str], jobs: int, done: dict[str, dict[str, Any]], fh: Any,
         progress: Callable[[int, int], None] | None, scheduler: Any,
         stamps: dict[str, str] | None = None) -> Iterator[dict[str, Any]]:
    """The records of ``names`` in order: finished ones from ``done``, the others estimated
    (written to ``fh`` with the file's stamp)."""
    todo = [n for n in names if n not in done]
    count = len(names) - len(todo)
    if progress is not None:
        progress(count, len(names))
    new = ordered_map(run_image, [(estimate_record, model, settings, (camera, n, max_objects))
                                  for n in todo], jobs=jobs, scheduler=scheduler)
    for name in names:
        if name in done:
            yield done[name]
            continue
        rec = next(new)
        if fh is not None:
            fh.write(json.dumps({**rec, "stamp": (stamps or {}).get(name, "")}) + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        count += 1
        if progress is not None:
            progress(count, len(names))
        yield rec


def estimate_bop_scene(estimator: Any, scene: str | Path, *, obj_id: int, max_objects: int = 1,
                       progress: Callable[[int], None] | None = None) -> list[str]:
    """BOP results lines (:func:`posevote.data.bop.results_rows`) for every image of a scene.

    Each image is estimated with its own camera (``scene_camera.json``); an
    object is written when its translation is known (a model that knows the
    object's height).
    """
    import time

    from posevote.data.bop import read_bop_images, results_rows

    folder = Path(scene)
    if not folder.name.isdigit():
        raise ValueError(f"{folder}: a BOP scene folder is named by its id (000001)")
    scene_id = int(folder.name)
    lines = []
    for im_id, image, camera in read_bop_images(folder):
        start = time.perf_counter()
        found = estimator.estimate_objects(image, max_objects, camera=camera)
        seconds = time.perf_counter() - start
        lines += [results_rows(scene_id, im_id, obj_id, r.best.score, r.best.R_cam_obj,
                               r.best.t_cam_obj, seconds)
                  for r in found if r.best is not None and r.best.t_cam_obj is not None]
        if progress is not None:
            progress(1)
    return lines
