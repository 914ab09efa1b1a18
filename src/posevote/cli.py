"""Command-line interface: ``posevote train | estimate | bop | presets | weights | evaluate | demo``.

Exit codes
----------
0  success
1  bad input: a missing, unreadable or malformed file or value (the message,
   on stderr as ``Error: ...``, names the file, row or argument)
2  usage error: unknown option, missing argument, an option value outside
   its range, or an output path that names a folder (or a file, for a
   results folder)
3  ``estimate`` found no object (no edges, or no mode above ``--min-score``)
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
from pathlib import Path
from typing import Any

import click

# The stages (numpy, OpenCV, numba, scipy, scikit-learn) are imported by the
# commands that use them, so that `posevote --help` starts at once.

EXIT_INPUT = 1
EXIT_NOT_FOUND = 3
#: What to try when nothing scored above ``min_score``.
NOT_FOUND_HINT = ("If the object is there: crop the image around it, give --scale-range "
                  "when it is much smaller or larger than in the training images (or "
                  "--camera with --depth-range), or --min-score 0 for the best pose "
                  "anyway (check its score and p).")


class InputError(click.ClickException):
    """A bad file or value: printed as ``Error: ...``, exit code 1."""

    exit_code = EXIT_INPUT


#: Suffixes the image outputs (overlays, weight plots) may be written with.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def _output_file(path: Path, option: str, *, suffixes: tuple[str, ...] | None = None) -> Path:
    """Refuse an output file path that names a folder or has the wrong suffix."""
    if path.is_dir():
        raise click.BadParameter(f"{path} is a folder; give a file name", param_hint=option)
    if suffixes is not None and path.suffix.lower() not in suffixes:
        raise click.BadParameter(f"{path}: the file name must end in one of "
                                 f"{', '.join(suffixes)}", param_hint=option)
    if path.parent.exists() and not path.parent.is_dir():
        raise click.BadParameter(f"{path.parent} is a file, not a folder", param_hint=option)
    return path


def _output_folder(path: Path, option: str) -> Path:
    """Refuse an output folder path that names a file."""
    if path.exists() and not path.is_dir():
        raise click.BadParameter(f"{path} is a file; give a folder", param_hint=option)
    return path


def _kernels_compiled() -> bool:
    """Whether numba's cache holds posevote's search kernels (compiled on first use)."""
    import posevote.inference

    # numba keeps its cache beside the module, or wholly in NUMBA_CACHE_DIR when it is set.
    place = Path(os.environ.get("NUMBA_CACHE_DIR") or
                 Path(posevote.inference.__file__).parent / "__pycache__")
    return place.is_dir() and next(place.rglob("voting.*.nbi"), None) is not None


def _first_run_notice() -> None:
    """Say, once after installing, why the first run is slow, and count the kernels as
    numba compiles them (this process's; workers compile their own in silence)."""
    if _kernels_compiled():
        return
    click.echo("preparing posevote's compiled kernels: once after installing, about 20 s "
               "...", err=True)
    import atexit

    from numba.core import event
    from tqdm import tqdm

    bar = tqdm(desc="compiled", unit=" kernels", file=sys.stderr, leave=False,
               disable=not sys.stderr.isatty())

    class _Counter(event.Listener):
        def on_start(self, ev: Any) -> None:
            pass

        def on_end(self, ev: Any) -> None:
            func = getattr((ev.data or {}).get("dispatcher"), "py_func", None)
            if getattr(func, "__module__", "").startswith("posevote."):
                bar.update(1)

    counter = _Counter()
    event.register("numba:compile", counter)

    live = [True]

    def done() -> None:
        if live.pop() if live else False:
            event.unregister("numba:compile", counter)
            bar.close()

    _FIRST_RUN_DONE.append(done)
    atexit.register(done)


#: What ends the first run's kernel count (:func:`_first_run_notice`).
_FIRST_RUN_DONE: list[Any] = []


def _first_run_done() -> None:
    """End the kernel count before a command prints its result on the same terminal."""
    while _FIRST_RUN_DONE:
        _FIRST_RUN_DONE.pop()()


def _say(message: str) -> None:
    """A line on stdout that a running kernel count (on the terminal's stderr) steps around."""
    if _FIRST_RUN_DONE:
        from tqdm import tqdm

        tqdm.write(message, file=sys.stdout)
    else:
        click.echo(message)


def _preset_name(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    """A ``--preset`` value that names a preset (a usage error otherwise)."""
    from posevote.presets import PRESETS

    if value is not None and value not in PRESETS:
        raise click.BadParameter(f"unknown preset {value!r}; choose one of "
                                 f"{', '.join(PRESETS)}")
    return value


def _input_error(exc: BaseException) -> InputError:
    """The ``Error:`` message for a bad input, naming the file where the exception knows it."""
    if isinstance(exc, BrokenPipeError):
        # The reader of the output went away (``| head``): click ends quietly.
        raise exc
    if isinstance(exc, OSError) and not isinstance(exc, FileNotFoundError) and exc.filename:
        return InputError(f"{exc.filename}: {exc.strerror or exc}")
    if isinstance(exc, MemoryError):
        return InputError("out of memory; downscale the image or use a coarser search")
    return InputError(str(exc))


#: What the commands turn into ``Error:`` messages (exit 1) rather than tracebacks.
BAD_INPUT = (OSError, ValueError, TypeError, MemoryError, ImportError)


def _bop_training(source: Path, objects: str | None, height: float | None) -> tuple[Any, float]:
    """A BOP scene's views of one object, and its height (given, or from the scene's cameras)."""
    from posevote.data.bop import read_bop_scene

    obj = _int_list(objects, option="--objects")
    if not obj or len(obj) != 1:
        raise click.BadParameter("--layout bop needs one obj_id", param_hint="--objects")
    scene = read_bop_scene(source, obj_id=obj[0])
    ts = scene.training_set
    return ts, height if height is not None else ts.object_height_m(scene.cameras)


def _object_height(ts: Any, camera_file: Path | None, height: float | None) -> float | None:
    """The object's height in metres: given, or from the training camera and distance_m."""
    import numpy as np

    from posevote.camera import read_camera

    if height is not None and camera_file is not None:
        raise click.BadParameter("give --object-height-m or --camera, not both",
                                 param_hint="--camera")
    if camera_file is not None:
        return ts.object_height_m(read_camera(camera_file))
    if height is None and np.isfinite(ts.distances).any():
        raise click.BadParameter("the distance_m column needs the training camera",
                                 param_hint="--camera")
    return height


def _parse_params(items: tuple[str, ...]) -> dict[str, Any]:
    """``--param`` items as :meth:`PoseEstimator.set_params` keys (``group.field`` -> ``group__field``)."""
    import dataclasses
    import difflib

    from posevote._options import parse_setting
    from posevote.estimator import PoseEstimator
    from posevote.pipeline import OPTION_GROUPS

    params: dict[str, Any] = {}
    top = list(PoseEstimator().get_params(deep=False))
    for item in items:
        name, sep, value = item.partition("=")
        if not sep:
            raise click.BadParameter(f"{item!r}: expected NAME=VALUE", param_hint="--param")
        group, dot, field = name.strip().partition(".")
        if group not in top or (dot and (group not in OPTION_GROUPS or field not in {
                f.name for f in dataclasses.fields(OPTION_GROUPS[group])})):
            valid = [*top, *(f"{g}.{f.name}" for g, c in OPTION_GROUPS.items()
                             for f in dataclasses.fields(c))]
            near = difflib.get_close_matches(name.strip(), valid, n=1, cutoff=0.6)
            hint = f"did you mean {near[0]!r}? " if near else ""
            raise click.BadParameter(f"unknown estimator parameter {name!r}; {hint}valid: "
                                     f"{', '.join(valid)}", param_hint="--param")
        if not dot and group in OPTION_GROUPS and value.strip() == "on":
            params[group] = OPTION_GROUPS[group]()
            continue
        if not dot and group in OPTION_GROUPS and value.strip() != "None":
            raise click.BadParameter(f"{item!r}: set the fields of {group} one by one "
                                     f"({group}.FIELD=VALUE), {group}=on for its defaults, or "
                                     f"{group}=None to switch it off", param_hint="--param")
        try:
            params[f"{group}__{field}" if dot else group] = parse_setting(value)
        except ValueError as err:
            raise click.BadParameter(f"{item!r}: {err}", param_hint="--param") from None
    return params


def _int_list(text: str | None, *, option: str) -> list[int] | None:
    if text is None:
        return None
    out: list[int] = []
    try:
        for part in text.split(","):
            if "-" in part:
                lo, hi = part.split("-")
                if not 0 <= int(hi) - int(lo) < 10_000:
                    raise click.BadParameter(f"{part!r}: a range low-high with low <= high, "
                                             "at most 10000 numbers", param_hint=option)
                out.extend(range(int(lo), int(hi) + 1))
            elif part.strip():
                out.append(int(part))
    except ValueError:
        raise click.BadParameter(f"{text!r}: expected numbers like 1,6,8 or 1-5",
                                 param_hint=option) from None
    return out


def _progress(total: int, label: str):
    from tqdm import tqdm

    return tqdm(total=total, desc=label, unit="img", file=sys.stderr, leave=False,
                disable=None)


class _DoneBar:
    """A progress bar fed ``(done, total)``, made when the total is first known."""

    def __init__(self, label: str) -> None:
        self.label = label
        self.bar: Any = None

    def __call__(self, done: int, total: int) -> None:
        if self.bar is None:
            self.bar = _progress(total, self.label)
        self.bar.update(done - self.bar.n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="posevote")
def cli() -> None:
    """posevote: find an object in a photograph and estimate its continuous 3D pose."""


@cli.command()
@click.argument("source", type=click.Path(path_type=Path))
@click.option("-o", "--output", "output", required=True, type=click.Path(path_type=Path),
              help="Model file to write (.npz).")
@click.option("--layout", type=click.Choice(["csv", "coil", "epfl", "bop"]), default="csv",
              show_default=True, help="SOURCE is a folder with poses.csv, COIL-100, EPFL "
                                      "tripod-seq or a BOP scene folder.")
@click.option("--objects", help="COIL object numbers, e.g. 6,8,23; BOP: one obj_id.")
@click.option("--cars", help="EPFL car numbers, e.g. 1-5.")
@click.option("--azimuth-step-deg", type=click.FloatRange(0, 180, min_open=True), default=None,
              help="COIL: train on the views at multiples of this step, a multiple of 5 "
                   "(default: all).")
@click.option("--camera", "camera_file", type=click.Path(path_type=Path), default=None,
              help="Training camera (JSON: fx, fy, cx, cy or K); with a distance_m column it "
                   "gives the object's metric height.")
@click.option("--object-height-m", type=click.FloatRange(0, 1e4, min_open=True), default=None,
              help="The object's height in metres (its box height), for poses in metres.")
@click.option("--allow-outside-paths", is_flag=True,
              help="Let poses.csv name images outside SOURCE (absolute or ../ paths).")
@click.option("--preset", default="default", show_default=True, callback=_preset_name,
              help="Named settings to start from (see `posevote presets`).")
@click.option("--no-weights", is_flag=True, help="Store the model with weights switched off.")
@click.option("--prune", type=click.Choice(["none", "moderate", "aggressive"]), default="none",
              show_default=True, help="Prune a category model by clustering (Sec. III-A).")
@click.option("--param", "params", multiple=True, metavar="NAME=VALUE",
              help="Override a preset value (repeatable), e.g. kernel.position_sigma=2.5 or "
                   "appearance=None.")
@click.option("--threads", type=click.IntRange(1, 64), default=1, show_default=True,
              help="Threads reading the images (faster on several cores; the same model).")
def train(source: Path, output: Path, layout: str, objects: str | None, cars: str | None,
          azimuth_step_deg: float | None, camera_file: Path | None,
          object_height_m: float | None, allow_outside_paths: bool, preset: str,
          no_weights: bool, prune: str, params: tuple[str, ...], threads: int) -> None:
    """Train a model from pose-annotated images in SOURCE.

    Several instances (an ``instance`` column, several COIL objects or EPFL
    cars) make a category model.
    """
    import numpy as np

    from posevote.data import read_coil, read_epfl, read_poses_csv
    from posevote.estimator import PoseEstimator
    from posevote.results import LOOKALIKE

    # A model file, never one of the inputs (poses.csv, an image) under another name.
    _output_file(output, "-o", suffixes=(".npz",))
    _first_run_notice()
    for value, option, wanted in ((objects, "--objects", "coil"), (cars, "--cars", "epfl"),
                                  (azimuth_step_deg, "--azimuth-step-deg", "coil")):
        if value is not None and layout != wanted and not (option == "--objects"
                                                           and layout == "bop"):
            raise click.BadParameter(f"applies to --layout {wanted} only", param_hint=option)
    if allow_outside_paths and layout != "csv":
        raise click.BadParameter("applies to --layout csv only", param_hint="--allow-outside-paths")
    if azimuth_step_deg is not None and not (
            math.isfinite(azimuth_step_deg)
            and abs(azimuth_step_deg / 5 - round(azimuth_step_deg / 5)) < 1e-9):
        raise click.BadParameter(f"{azimuth_step_deg:g}: COIL-100 has a view every 5 degrees; "
                                 "give a multiple of 5", param_hint="--azimuth-step-deg")
    settings = _parse_params(params)
    if no_weights:
        settings["weights"] = False
    if prune != "none":
        settings["prune"] = prune
    height: float | None = None
    try:
        if layout == "csv":
            ts = read_poses_csv(source, allow_outside_paths=allow_outside_paths)
        elif layout == "coil":
            obj = _int_list(objects, option="--objects")
            if not obj:
                raise click.BadParameter("--layout coil needs --objects", param_hint="--objects")
            azimuths = None if azimuth_step_deg is None else np.arange(0, 360, azimuth_step_deg)
            ts = read_coil(source, objects=obj, azimuths_deg=azimuths)
        elif layout == "bop":
            ts, height = _bop_training(source, objects, object_height_m)
        else:
            car_list = _int_list(cars, option="--cars")
            if not car_list:
                raise click.BadParameter("--layout epfl needs --cars", param_hint="--cars")
            ts = read_epfl(source, cars=car_list)
        if layout != "bop":
            height = _object_height(ts, camera_file, object_height_m)
        est = PoseEstimator.from_preset(preset, **settings)
        est._settings()   # checks the stored n_jobs too, before the threads replace it
        jobs = est.n_jobs
        est.set_params(n_jobs=threads)
        shrunk = [f"{v:g}" for v in est.search.image_levels if v > 1.0]
        done = 0
        with _progress(len(ts), "features") as bar:
            def read(n: int) -> None:
                nonlocal done
                bar.update(n)
                # Counted here: a bar off (no terminal) counts nothing.
                done += n
                if done == len(ts) and (est.weights or shrunk):   # no bar follows: say so
                    bar.close()
                    steps = ([f"weighing the features of {len(ts)} views (Eq. 4; a minute "
                              "or more past a thousand views)"] if est.weights else []) + (
                        [f"learning the views shrunk for image level(s) {', '.join(shrunk)}"]
                        if shrunk else [])
                    click.echo(", then ".join(steps) + " ...", err=True)

            est.fit(list(ts.images), ts.poses, boxes=ts.boxes,
                    masks=list(ts.masks) if ts.masks else None,
                    instances=list(ts.instances) if ts.instances and all(ts.instances) else None,
                    category=ts.category, progress=read, object_height_m=height,
                    origins=ts.origins if len(ts.origins) else None)
        # The threads were this machine's choice, not the model's.
        est.set_params(n_jobs=jobs)
        est.save(output)
    except BAD_INPUT as exc:
        raise _input_error(exc) from None
    _first_run_done()
    m, full = est.model_, est.full_model_
    kept = "" if m is full else f" (pruned from {full.n_features})"
    click.echo(f"trained on {m.n_views} images ({len(m.instance_names)} instance(s)), "
               f"{m.n_features} features{kept}, mean weight {full.weight.mean():.2f} -> {output}")
    alike = 0 if m.view_lookalike is None else int(np.sum(m.view_lookalike >= LOOKALIKE))
    if alike:
        click.echo(f"{alike} of {m.n_views} views look alike from another side 30 deg or more "
                   f"away (lookalike >= {LOOKALIKE:g}): estimates there will be ambiguous, "
                   "their azimuth undefined by the object's edges")


@cli.command()
@click.argument("model", type=click.Path(path_type=Path))
@click.argument("images", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print one JSON line per image.")
@click.option("--csv", "as_csv", is_flag=True,
              help="Print one CSV row per image (the best mode), with a header.")
@click.option("--out", "out", type=click.Path(path_type=Path), default=None,
              help="Results folder (estimates.jsonl, estimates.csv); rerun to resume.")
@click.option("--jobs", type=click.IntRange(1, 64), default=1, show_default=True,
              help="Worker processes for the images.")
@click.option("--max-objects", type=click.IntRange(1, 100), default=1, show_default=True,
              help="Objects to find per image (one line each).")
@click.option("--scheduler", default=None, metavar="tcp://HOST:PORT",
              help="Estimate the images on this Dask cluster instead of --jobs.")
@click.option("--overlay", type=click.Path(path_type=Path),
              help="Write the image with the box and an orientation rose (one image only).")
@click.option("--inplane-range-deg", nargs=2, type=float, default=None,
              help="In-plane angles searched, e.g. -30 30.")
@click.option("--scale-range", nargs=2, type=float, default=None,
              help="Scales searched relative to training, e.g. 0.7 1.3 (on the image as "
                   "given: these scales only).")
@click.option("--depth-range", nargs=2, type=float, default=None, metavar="NEAR FAR",
              help="Depths of the object searched, metres (with --camera; sets the scales).")
@click.option("--no-fitting", is_flag=True,
              help="Skip the continuous refinement: the modes are the best probes (polished "
                   "where the preset refines locally).")
@click.option("--min-score", type=float, default=None,
              help="Report 'not found' when no mode's detection score (contrast where the "
                   "preset measures it, else score) is above this.")
@click.option("--threads", type=click.IntRange(1, 64), default=1, show_default=True,
              help="Threads probing viewpoints at once (faster on several cores; same result).")
@click.option("--camera", "camera_file", type=click.Path(path_type=Path), default=None,
              help="Test camera (JSON: fx, fy, cx, cy or K): adds R_cam_obj and t_cam_obj.")
def estimate(model: Path, images: tuple[Path, ...], as_json: bool, as_csv: bool,
             out: Path | None, jobs: int, max_objects: int, scheduler: str | None,
             overlay: Path | None,
             inplane_range_deg: tuple[float, float] | None, scale_range: tuple[float, float] | None,
             depth_range: tuple[float, float] | None,
             no_fitting: bool, min_score: float | None, threads: int,
             camera_file: Path | None) -> None:
    """Estimate the pose of the object in each of IMAGES (files, folders, glob patterns).

    Each pose comes with its score (the weighted share of the model's features
    the image explains), with the cluttered preset its contrast (the score over
    the spread of what the same pose scores elsewhere in the frame: what decides
    "found" there), and p, the chance that it is right (within 30 degrees, the
    box on the object), calibrated for the preset on development data with
    flips, other objects and empty frames in it.

    Exit code 3 when no image holds an object; 1 when an image could not be
    read (the others are still estimated).
    """
    from posevote.batch import expand_images
    from posevote.camera import read_camera, scale_range_for_depths
    from posevote.estimator import PoseEstimator
    from posevote.inference.setup import SCALE_LIMITS

    if as_json and as_csv:
        raise click.BadParameter("give --json or --csv, not both", param_hint="--csv")
    if depth_range is not None and camera_file is None:
        raise click.BadParameter("needs --camera (depths become scales through it)",
                                 param_hint="--depth-range")
    if depth_range is not None and scale_range is not None:
        raise click.BadParameter("give --depth-range or --scale-range, not both",
                                 param_hint="--depth-range")
    if overlay is not None:
        _output_file(overlay, "--overlay", suffixes=IMAGE_SUFFIXES)
    if out is not None:
        _output_folder(out, "--out")
    _first_run_notice()
    try:
        est = PoseEstimator.load(model)
        camera = None if camera_file is None else read_camera(camera_file)
        changes: dict[str, Any] = {"n_jobs": threads}
        if inplane_range_deg is not None:
            changes["search__inplane_range_deg"] = tuple(inplane_range_deg)
        if depth_range is not None and camera is not None:
            try:
                scale_range = scale_range_for_depths(
                    depth_range, camera, object_height_m=est.object_height_m_,
                    reference_size_px=est.model_.reference_size)
            except ValueError as exc:
                raise click.BadParameter(str(exc), param_hint="--depth-range") from None
            lo, hi = SCALE_LIMITS
            if not lo <= scale_range[0] <= scale_range[1] <= hi:
                raise click.BadParameter(
                    f"{depth_range[0]:g}-{depth_range[1]:g} m are {scale_range[0]:.3g}-"
                    f"{scale_range[1]:.3g} times the training size, outside {lo:g}-{hi:g}",
                    param_hint="--depth-range")
        if scale_range is not None:
            # The levels would search the range at other sizes too: these scales only.
            changes["search__scale_range"] = tuple(scale_range)
            changes["search__scale_steps"] = max(est.search.scale_steps, 5)
            changes["search__image_levels"] = (1.0,)
        if no_fitting:
            changes["refine"] = dataclasses.replace(
                est.refine, fit=False, rescale=False,
                local=None if est.refine.local is None else "polish")
        if min_score is not None:
            changes["min_score"] = min_score
        est.set_params(**changes)
        paths = expand_images(images)
        if overlay is not None and len(paths) != 1:
            raise click.BadParameter(f"applies to one image; {len(paths)} given",
                                     param_hint="--overlay")
        if overlay is not None and overlay.resolve() == paths[0].resolve():
            raise click.BadParameter(f"{overlay} is the image itself; give another file name",
                                     param_hint="--overlay")
        if len(paths) == 1 and out is None and not as_csv and max_objects == 1 \
                and scheduler is None:
            _estimate_one(est, paths[0], as_json=as_json, overlay=overlay, camera=camera)
            return
        changes.pop("n_jobs")
        found, failed = _estimate_many(model, paths, changes, camera, jobs=jobs, out=out,
                                       as_json=as_json, as_csv=as_csv, threads=threads,
                                       max_objects=max_objects, scheduler=scheduler)
    except BAD_INPUT as exc:
        raise _input_error(exc) from None
    if failed:
        raise InputError(f"{failed} of {len(paths)} images could not be estimated (above)")
    if not found:
        sys.exit(EXIT_NOT_FOUND)


def _pose_line(b: Any) -> str:
    return (f"azimuth {b.azimuth_deg:.1f} deg  elevation {b.elevation_deg:.1f} deg  "
            f"in-plane {b.inplane_deg:.1f} deg  scale {b.scale:.3f}  "
            f"position ({b.position[0]:.1f}, {b.position[1]:.1f}) px  score {b.score:.3f}  "
            f"{_contrast(b)}p {b.probability:.2f}{'' if b.refined else '  (not refined)'}")


def _contrast(b: Any) -> str:
    return "" if math.isnan(b.contrast) else f"contrast {b.contrast:.2f}  "


def _estimate_one(est: Any, image: Path, *, as_json: bool, overlay: Path | None,
                  camera: Any) -> None:
    """One image: the pose, its modes and (given a camera) its place, as text or JSON."""
    from posevote.data import read_image

    img = read_image(image)
    result = est.estimate(img, camera=camera)
    _first_run_done()
    if overlay is not None:
        from posevote.evaluation.plots import draw_overlay, write_png

        write_png(overlay, draw_overlay(img, result))
    if as_json:
        click.echo(json.dumps({"image": str(image), **result.to_dict()}))
    elif result.best is not None:
        b = result.best
        click.echo(_pose_line(b))
        if b.R_cam_obj is not None:
            click.echo("  R_cam_obj " + " ".join(
                "[" + " ".join(f"{x:+.4f}" for x in row) + "]" for row in b.R_cam_obj))
        if b.t_cam_obj is not None:
            click.echo("  t_cam_obj [" + " ".join(f"{x:+.4f}" for x in b.t_cam_obj) + "] m")
        elif b.R_cam_obj is not None:
            click.echo("  t_cam_obj unknown: the model has no object height (train with "
                       "--object-height-m, or --camera and a distance_m column)")
        for rank, m in enumerate(result.modes[1:], start=2):
            click.echo(f"  mode {rank}: azimuth {m.azimuth_deg:.1f} deg  score {m.score:.3f}  "
                       f"{_contrast(m)}p {m.probability:.2f}")
        if result.ambiguous and not b.probability >= 0.5:
            click.echo("  ambiguous: the best mode is more likely wrong than right (look again)")
        elif result.ambiguous:
            click.echo(f"  ambiguous: the object looks alike from another side here (lookalike "
                       f"{b.lookalike:.2f}): its azimuth is not defined by its edges")
    elif result.top_score > 0:
        what = "contrast" if est.search.contrast else "score"
        click.echo(f"no object found (best {what} {result.top_score:.3f}, below "
                   f"min_score {est.min_score:g}). {NOT_FOUND_HINT}", err=True)
    else:
        click.echo("no object found (no edges to vote)", err=True)
    if not result.found:
        sys.exit(EXIT_NOT_FOUND)


def _estimate_many(model: Path, paths: list[Path], changes: dict[str, Any], camera: Any, *,
                   jobs: int, out: Path | None, as_json: bool, as_csv: bool,
                   threads: int, max_objects: int, scheduler: str | None) -> tuple[int, int]:
    """Several images: one line per image and object, in order; returns (found, failed)."""
    import csv
    import io

    from posevote.batch import CSV_FIELDS, csv_row, estimate_images, object_records

    if as_csv:
        click.echo(",".join(CSV_FIELDS))
    found = failed = 0
    with _progress(len(paths), "images") as bar:
        records = estimate_images(model, paths, settings={**changes, "n_jobs": threads},
                                  camera=None if camera is None else camera.to_dict(),
                                  jobs=jobs, max_objects=max_objects, out=out, scheduler=scheduler,
                                  progress=lambda d, t: bar.update(d - bar.n),
                                  log=lambda m: click.echo(m, err=True))
        for image_record in records:
            found += bool(image_record.get("found"))
            if "error" in image_record:
                failed += 1
                click.echo(f"Error: {image_record['error']}", err=True)
            for rec in object_records(image_record):
                if as_json:
                    click.echo(json.dumps(rec))
                elif as_csv:
                    # The row's own terminator, so that a name holding a newline is quoted.
                    line = io.StringIO()
                    csv.writer(line, lineterminator="\n").writerow(csv_row(rec))
                    click.echo(line.getvalue(), nl=False)
                elif rec.get("best"):
                    b = rec["best"]
                    label = f" object {rec['object'] + 1}" if max_objects > 1 else ""
                    click.echo(f"{rec['image']}{label}: azimuth {b['azimuth_deg']:.1f} deg  "
                               f"elevation {b['elevation_deg']:.1f} deg  in-plane "
                               f"{b['inplane_deg']:.1f} deg  scale {b['scale']:.3f}  position "
                               f"({b['position_px'][0]:.1f}, {b['position_px'][1]:.1f}) px  "
                               f"score {b['score']:.3f}{_batch_trust(rec)}")
                elif "error" not in rec:
                    click.echo(f"{rec['image']}: no object found")
    if found + failed < len(paths):
        click.echo(NOT_FOUND_HINT, err=True)
    return found, failed


def _batch_trust(record: dict[str, Any]) -> str:
    """The probability of an image's best mode, and whether it is ambiguous, for its line."""
    p = record["best"].get("probability")
    return ("" if p is None else f"  p {p:.2f}") + ("  ambiguous" if record.get("ambiguous")
                                                   else "")


@cli.command()
@click.argument("model", type=click.Path(path_type=Path))
@click.argument("scenes", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--obj-id", type=click.IntRange(0, 10**6), required=True,
              help="The BOP object id the model was trained on.")
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path),
              help="BOP results CSV to write (scene_id,im_id,obj_id,score,R,t,time).")
@click.option("--max-objects", type=click.IntRange(1, 100), default=1, show_default=True,
              help="Objects to find per image.")
def bop(model: Path, scenes: tuple[Path, ...], obj_id: int, output: Path,
        max_objects: int) -> None:
    """Estimate every image of BOP SCENES (folders) and write the BOP results CSV."""
    from posevote.batch import estimate_bop_scene
    from posevote.data.bop import write_bop_results
    from posevote.estimator import PoseEstimator

    _output_file(output, "-o", suffixes=(".csv",))
    try:
        est = PoseEstimator.load(model)
        if est.object_height_m_ is None:
            raise ValueError(f"{model}: the model does not know the object's height, so it "
                             "cannot give t; train it with --layout bop or --object-height-m")
        lines: list[str] = []
        for scene in scenes:
            lines += estimate_bop_scene(est, scene, obj_id=obj_id, max_objects=max_objects)
        write_bop_results(output, lines)
    except BAD_INPUT as exc:
        raise _input_error(exc) from None
    click.echo(f"{len(lines)} estimates of object {obj_id} in {len(scenes)} scene(s) -> {output}")


@cli.command()
@click.option("-v", "--verbose", is_flag=True,
              help="Also print each preset's steps, in the order they run, and its parameters.")
def presets(verbose: bool) -> None:
    """List the named presets, what each is for and where it was chosen."""
    from posevote.estimator import PoseEstimator
    from posevote.pipeline import Settings, describe
    from posevote.presets import PRESETS

    for p in PRESETS.values():
        click.echo(f"{p.name:10s} {p.description}")
        click.echo(f"{'':10s} chosen on: {p.chosen_on} ({p.script})")
        if verbose:
            est = PoseEstimator.from_preset(p.name)
            steps = describe(Settings.of(est.get_params(deep=False)))
            click.echo(f"{'':10s} steps: {' -> '.join(steps)}")
            click.echo(f"{'':10s} {est!r}")


@cli.command()
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path),
              help="PNG file to write (its geometry goes beside it, as .json).")
@click.option("--squares", nargs=2, type=click.IntRange(3, 40), default=(7, 5),
              show_default=True, help="Chessboard squares across and down.")
@click.option("--square-mm", type=click.FloatRange(2.0, 1000.0), default=40.0,
              show_default=True, help="A square's side as printed, millimetres.")
@click.option("--marker-mm", type=click.FloatRange(1.0, 999.0), default=30.0,
              show_default=True, help="An ArUco marker's side as printed, millimetres.")
@click.option("--dpi", type=click.IntRange(72, 1200), default=300, show_default=True,
              help="Print resolution of the image.")
def board(output: Path, squares: tuple[int, int], square_mm: float, marker_mm: float,
          dpi: int) -> None:
    """Write a ChArUco board to print at 100% (no scaling) and stand the object on, for
    `posevote capture`."""
    from posevote.capture import BoardSpec, write_board

    _output_file(output, "-o", suffixes=(".png",))
    try:
        spec = BoardSpec(squares=squares, square_m=square_mm / 1000.0,
                         marker_m=marker_mm / 1000.0)
        geometry = write_board(output, spec, dpi=dpi)
    except BAD_INPUT as exc:
        raise _input_error(exc) from None
    width, height = spec.size_m
    click.echo(f"wrote {output} ({width * 1000:.0f} x {height * 1000:.0f} mm of squares at "
               f"{dpi} dpi; print at 100%, then measure a square: {square_mm:g} mm) and "
               f"{geometry}")


@cli.command()
@click.argument("photos", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path),
              help="Training folder to write (images, poses.csv, camera.json).")
@click.option("--board", "board_file", type=click.Path(path_type=Path), default=None,
              help="The board's .json from `posevote board` [default: its defaults].")
@click.option("--height-mm", type=click.FloatRange(1.0, 10000.0), required=True,
              help="The object's height, millimetres.")
@click.option("--radius-mm", type=click.FloatRange(1.0, 10000.0), required=True,
              help="The radius of a cylinder standing on the board that holds the object.")
@click.option("--centre-mm", nargs=2, type=float, default=None,
              help="Where the object stands: millimetres from the board's top-left "
                   "chessboard corner, right and down as printed [default: the board's "
                   "centre].")
@click.option("--camera", "camera_file", type=click.Path(path_type=Path), default=None,
              help="The camera file; default: calibrated from the photographs.")
@click.option("--max-error-px", type=click.FloatRange(0.1, 20.0), default=1.5,
              show_default=True, help="Refuse photographs whose board fits worse (RMS px).")
def capture(photos: tuple[Path, ...], output: Path, board_file: Path | None, height_mm: float,
            radius_mm: float, centre_mm: tuple[float, float] | None, camera_file: Path | None,
            max_error_px: float) -> None:
    """Make a training folder from PHOTOS (files, folders, patterns) of the object standing
    on the printed board: each photograph's pose and box from the board, the camera
    calibrated from them; then `posevote train OUTPUT -o model.npz`."""
    from posevote.batch import expand_images
    from posevote.camera import read_camera
    from posevote.capture import BoardSpec, Footprint
    from posevote.capture import capture as run_capture

    _output_folder(output, "-o")
    try:
        spec = BoardSpec() if board_file is None else BoardSpec.read(board_file)
        width, height = spec.size_m
        centre = (width / 2, height / 2) if centre_mm is None else \
            (centre_mm[0] / 1000.0, centre_mm[1] / 1000.0)
        footprint = Footprint(centre_m=centre, radius_m=radius_mm / 1000.0,
                              height_m=height_mm / 1000.0)
        camera = None if camera_file is None else read_camera(camera_file)
        paths = expand_images(photos)
        with _progress(len(paths), "photographs") as bar:
            report = run_capture(paths, output, footprint=footprint, spec=spec, camera=camera,
                                 max_error_px=max_error_px, progress=bar.update)
    except BAD_INPUT as exc:
        raise _input_error(exc) from None
    for name, why in report.refused:
        click.echo(f"refused {name}: {why}", err=True)
    cam = report.camera
    source = ("calibrated from the photographs, RMS "
              f"{report.calibration_rms_px:.2f} px" if report.calibration_rms_px is not None
              else f"from {camera_file}")
    click.echo(f"camera fx {cam.fx:.1f} fy {cam.fy:.1f} cx {cam.cx:.1f} cy {cam.cy:.1f} "
               f"dist {[round(d, 4) for d in cam.dist]} ({source})")
    masked = sum(bool(r["mask"]) for r in report.kept)
    click.echo(f"{len(report.kept)} of {len(paths)} photographs ({masked} with a mask) -> "
               f"{output}/poses.csv (then: posevote train {output} --camera "
               f"{output}/camera.json -o model.npz; estimate with --camera "
               f"{output}/camera.json)")


@cli.command()
@click.argument("model", type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path),
              help="PNG file to write.")
@click.option("--views", type=click.IntRange(1, 24), default=6, show_default=True,
              help="Number of training views shown.")
def weights(model: Path, output: Path, views: int) -> None:
    """Draw the model's feature weights (the paper's Fig. 3)."""
    from posevote.estimator import PoseEstimator
    from posevote.evaluation.plots import plot_weights

    _output_file(output, "-o", suffixes=(".png", ".pdf", ".svg"))
    try:
        est = PoseEstimator.load(model)
        plot_weights(est.model_, output, n_views=views)
    except BAD_INPUT as exc:
        raise _input_error(exc) from None
    click.echo(f"wrote {output}")


@cli.command()
@click.argument("protocol", type=click.Choice(["coil-category", "coil-loio", "epfl-single",
                                               "epfl-10-10", "epfl-cv", "rendered-sphere",
                                               "rendered-capture", "frames"]))
@click.option("--data", type=click.Path(path_type=Path), default=None,
              help="Data folder: ../shared/data, or the dataset's own folder (not for "
                   "rendered-sphere and rendered-capture, which render their own).")
@click.option("--out", "out", type=click.Path(path_type=Path), default=None,
              help="Results folder (default: results/PROTOCOL). Rerun with the same folder "
                   "to resume.")
@click.option("--jobs", type=click.IntRange(1, 64), default=1, show_default=True,
              help="Worker processes for the test images.")
@click.option("--every", type=click.IntRange(1, 1000), default=1, show_default=True,
              help="Test every N-th image only (a quick look; the report says so).")
@click.option("--rows", default=None,
              help="Comma-separated row names to run, or 'all' (default: all rows, except "
                   "for epfl-10-10: its main row, to keep within 15 minutes with --jobs 2).")
@click.option("--scheduler", default=None, metavar="tcp://HOST:PORT",
              help="Estimate the test images on this Dask cluster instead of --jobs "
                   "(pip install 'posevote[dask]').")
@click.option("--images", type=click.IntRange(1, 10_000), default=None,
              help="rendered-sphere: test images [default: 40]; rendered-capture: test "
                   "images off the board [default: 24]; frames: frames with the object per "
                   "object and size [default: 2].")
@click.option("--preset", default=None, callback=_preset_name,
              help="frames only: the preset of the objects' models [default: cluttered].")
def evaluate(protocol: str, data: Path | None, out: Path | None, jobs: int, every: int,
             rows: str | None, scheduler: str | None, images: int | None,
             preset: str | None) -> None:
    """Run an evaluation PROTOCOL (the paper's, on real data; the rendered sphere; the
    rendered capture check; the frames benchmark)."""
    from posevote.evaluation.protocols import load_protocol
    from posevote.evaluation.report import markdown_table
    from posevote.evaluation.runner import run_protocol

    out = _output_folder(out if out is not None else Path("results") / protocol, "--out")
    _first_run_notice()
    if preset is not None and protocol != "frames":
        raise click.BadParameter("only for frames", param_hint="--preset")
    if protocol == "frames":
        for name, given in (("--every", every != 1), ("--rows", rows is not None)):
            if given:
                raise click.BadParameter("not used by frames", param_hint=name)
        if data is None:
            raise click.BadParameter("frames needs the data folder", param_hint="--data")
        _evaluate_frames(out, data, jobs=jobs, scheduler=scheduler, frames=images or 2,
                         preset=preset or "cluttered")
        return
    if protocol == "rendered-sphere":
        for name, given in (("--data", data is not None), ("--every", every != 1),
                            ("--rows", rows is not None)):
            if given:
                raise click.BadParameter("not used by rendered-sphere", param_hint=name)
        _evaluate_sphere(out, jobs=jobs, scheduler=scheduler, images=images or 40)
        return
    if protocol == "rendered-capture":
        for name, given in (("--data", data is not None), ("--every", every != 1),
                            ("--rows", rows is not None), ("--scheduler", scheduler is not None),
                            ("--jobs", jobs != 1)):
            if given:
                raise click.BadParameter("not used by rendered-capture", param_hint=name)
        _evaluate_capture(out, images=images or 24)
        return
    if data is None:
        raise click.BadParameter(f"{protocol} needs the data folder", param_hint="--data")
    if images is not None:
        raise click.BadParameter("only for rendered-sphere and frames", param_hint="--images")
    try:
        proto = load_protocol(protocol, data)
        row_list = None if rows is None else [r.strip() for r in rows.split(",") if r.strip()]
        progress = _DoneBar(protocol)
        try:
            summary = run_protocol(proto, out, jobs=jobs, every=every, rows=row_list,
                                   progress=progress, log=lambda m: click.echo(m, err=True),
                                   scheduler=scheduler)
        finally:
            progress.close()
    except BAD_INPUT as exc:
        raise _input_error(exc) from None
    click.echo(markdown_table(summary))
    if proto.published:
        click.echo("Published numbers to compare with:\n")
        click.echo(proto.published)
    click.echo(f"report, summary.json, results.csv and plots in {out}/")


def _evaluate_frames(out: Path, data: Path, *, jobs: int, scheduler: str | None, frames: int,
                     preset: str) -> None:
    from posevote.evaluation.frames import FramesSetup, report_text, run_frames
    from posevote.presets import get_preset

    try:
        get_preset(preset)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--preset") from None
    setup = FramesSetup(preset=preset, frames=frames)
    progress = _DoneBar("frames")
    try:
        summary = run_frames(setup, data, out, jobs=jobs, scheduler=scheduler,
                             progress=progress, log=lambda m: click.echo(m, err=True))
    except BAD_INPUT as exc:
        raise _input_error(exc) from None
    finally:
        progress.close()
    click.echo(report_text(setup, summary))
    click.echo(f"report, summary.json, records.jsonl and calibration.png in {out}/")


def _evaluate_capture(out: Path, *, images: int) -> None:
    from posevote.evaluation.capture_check import CaptureSetup, report_text, run_capture_check

    try:
        summary = run_capture_check(CaptureSetup(tests=images), out,
                                    log=lambda m: click.echo(m, err=True))
    except BAD_INPUT as exc:
        raise _input_error(exc) from None
    click.echo(report_text(summary))
    click.echo(f"report and summary.json in {out}/; the photographs in {out}/photos, the "
               f"captured training folder in {out}/captured")


def _evaluate_sphere(out: Path, *, jobs: int, scheduler: str | None, images: int) -> None:
    from posevote.evaluation.sphere import SphereSetup, report_text, run_sphere

    setup = SphereSetup(n_images=images)
    progress = _DoneBar("rendered-sphere")
    try:
        summary = run_sphere(setup, out, jobs=jobs, scheduler=scheduler, progress=progress,
                             log=lambda m: click.echo(m, err=True))
    except BAD_INPUT as exc:
        raise _input_error(exc) from None
    finally:
        progress.close()
    click.echo(report_text(setup, summary, summary["n_training_views"]))
    click.echo(f"report, summary.json, records.jsonl and rotation_errors.png in {out}/")


@cli.command()
@click.option("-o", "--output", type=click.Path(path_type=Path), default=Path("demo-output"),
              show_default=True, help="Folder for overlays and results.csv.")
@click.option("--images", "n_test", type=click.IntRange(1, 500), default=24, show_default=True,
              help="Number of test images.")
@click.option("--seed", type=click.IntRange(0, 2**32 - 1), default=0, show_default=True)
def demo(output: Path, n_test: int, seed: int) -> None:
    """Train on a rendered turntable and estimate cluttered, occluded test images."""
    from posevote.demo import run_demo

    _output_folder(output, "-o")
    _first_run_notice()
    try:
        summary = run_demo(output, n_test=n_test, seed=seed, log=_say)
    except BAD_INPUT as exc:
        raise _input_error(exc) from None
    _first_run_done()
    click.echo(f"\nazimuth error over {summary['n']} cluttered, 20%-occluded test images: "
               f"median {summary['median']:.1f} deg, mean {summary['mean']:.1f} deg, "
               f"{summary['under_22_5']:.0f}% under 22.5 deg; position within 5 px: "
               f"{summary['position_within_5px']:.0f}%")
    click.echo(f"found at the preset's threshold (detection score over "
               f"{summary['threshold']:g}): {summary['found']} of {summary['n']}, "
               f"{summary['found_right']} of them within 22.5 deg")
    click.echo(f"overlays and results.csv in {output}/")


def main() -> None:
    """Console-script entry point."""
    cli(prog_name="posevote")


if __name__ == "__main__":
    main()
