"""Regenerate docs/RESULTS.md from the evaluation protocols' result folders.

With ``--run``, first runs (or resumes) ``posevote evaluate`` for each
protocol and records its wall time; without it, only collects what the
result folders already hold. Each protocol's ``report.md`` and plots are
copied to ``docs/results/<protocol>/``; RESULTS.md links them, with the
instance-level benchmark files and the pruning benchmark (Fig. 4) that the
other scripts in this folder write. Nothing in RESULTS.md is typed by hand.

Usage::

    python benchmarks/make_results.py [--run] [--data ../shared/data] [--jobs 2]
        [--results results] [--epfl-cv-every 4]
        [--protocols coil-category,coil-loio,epfl-single,epfl-cv]
"""

from __future__ import annotations

import argparse
import json
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

from posevote.evaluation.protocols import load_protocol

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

INTRO = """# Results

Every number here comes from a script; this page is written by
`benchmarks/make_results.py` from the result folders of `posevote evaluate`
and from the files the other benchmark scripts write (their command is the
first line of each). Machine: 2 cores, Python 3.11; each process uses one
core; `--jobs 2` runs two.

## COIL-100, one instance model per object (issue 2)

16 objects, each trained on its views at 0, 20, ..., 340° and tested on its
other 54; boxes and flat bottles scored on the half circle.

- Clean test views (128×128): [`results/coil_instance.md`](results/coil_instance.md)
- The same views pasted at a random position, scale 0.7-1.3 and in-plane
  angle ±30° on cluttered photographs with 20% of the object hidden:
  [`results/coil_instance_clutter.md`](results/coil_instance_clutter.md)

Rejection of other objects (`min_score`, issue 25): each of the 40
development objects' models against its own views between training views,
views of the 39 others and background crops, 5-fold cross-validation over
objects: [`results/rejection_threshold.md`](results/rejection_threshold.md)
(clean views, the `default` preset) and
[`results/rejection_threshold_clutter.md`](results/rejection_threshold_clutter.md)
(pasted on clutter, the `cluttered` preset). The other presets' thresholds
(issue 63): at most 2.5% of empty frames reporting an object, 5-fold
cross-validation on the frames benchmark (`cluttered`, `turntable`) and on
epfl-cv with empty mosaics of photographs (`category`):
[`results/default_thresholds.md`](results/default_thresholds.md). Each
preset's probability calibration (issue 63), fitted and 5-fold
cross-validated on the same kinds of data with the wrong answers in them,
with its reliability and risk-coverage plots:
[`results/probability_calibration.md`](results/probability_calibration.md).

The whole viewing sphere (issue 28): pybullet's r2d2 rendered at
elevations -30 to 60° (the features morphed between neighbouring views),
tested pasted on clutter, with rotation and
translation errors in the camera frame (the translation against the mesh
origin, which the model learns in each training view), `posevote evaluate rendered-sphere
--jobs 2` ([`results/rendered-sphere/report.md`](results/rendered-sphere/report.md),
the errors plotted in
[`results/rendered-sphere/rotation_errors.png`](results/rendered-sphere/rotation_errors.png));
variants by `benchmarks/rendered_sphere.py`: the same views as rendered, on black:
[`results/rendered_sphere_clean.md`](results/rendered_sphere_clean.md) (`--clean`); one
elevation in the same clutter:
[`results/rendered_sphere_turntable.md`](results/rendered_sphere_turntable.md)
(`--elevations 15`); the test depths told to the estimator, as `posevote
estimate --depth-range` does:
[`results/rendered_sphere_known_depths.md`](results/rendered_sphere_known_depths.md)
(`--known-depths`).

Capture from a printed board (issue 65): a textured duck rendered standing
on the board, photographed from around through a distorting lens, captured,
trained and tested off the board against a model of the true poses, boxes
and masks, over three seeds: `benchmarks/capture_check.py`
([`results/capture_check.md`](results/capture_check.md)); one seed with its
files: `posevote evaluate rendered-capture`.

Found means found (issue 63): the 40 development COIL objects looked for in
640×480 and 1280×720 mosaics of EPFL frames at 0.4-3 times their training
size, and frames without them, `posevote evaluate frames --data ../shared/data
--jobs 2` ([`results/frames/report.md`](results/frames/report.md), the
calibration in [`results/frames/calibration.png`](results/frames/calibration.png)).

All 40 development objects of `../shared/data/coil-100` (the paper's 16 and
the 24 added for cross-validation, among them objects that look alike from
every side), the same protocol, with each estimate's best-mode probability:
[`results/coil_instance_40.md`](results/coil_instance_40.md).

Mode probabilities (issue 26): how often the best mode is right against the
probability it was given, on the records of `coil-loio` (where the sharpness
was chosen):
[`results/mode_calibration.md`](results/mode_calibration.md); on the five
`epfl-cv` folds, where it does not carry over:
[`results/mode_calibration_epfl.md`](results/mode_calibration_epfl.md).

![reliability on coil-loio](results/mode_calibration.png)

One estimate with its viewpoints probed by 1 or 2 threads (`n_jobs`, the same
estimate either way): [`results/time_threads.md`](results/time_threads.md)
(`python benchmarks/time_threads.py --markdown docs/results/time_threads.md`).
"""

PRUNING = """
## Category models: model size and pruning (Fig. 4, issue 4)

`python benchmarks/pruning.py --markdown docs/results/pruning.md --plot docs/results/pruning_fig4.png`

"""

OUTRO = """
## epfl-10-10 (cars 1-10 train, 11-20 test)

Cars 11-20 are a held-out test set that is not in `../shared`, so this
protocol has not been run here. Its wall time is projected by timing the
same training and estimation on stand-in frames of cars 1-10:
[`results/time_epfl_10_10.md`](results/time_epfl_10_10.md)
(`python benchmarks/time_epfl_10_10.py --markdown docs/results/time_epfl_10_10.md`).
`posevote evaluate epfl-10-10` runs its main row by default, to keep within
the 15 minutes of issue 3 (`--rows all` adds the paper's row, edges alone,
and the two pruning rows; the paper's row beside the preset's is in every
`epfl-cv` table).

## Speed

posevote's time per image on one thread, beside OpenCV LINE-2D on the same
EPFL frames, with the targets of issue 27:
[`results/speed.md`](results/speed.md)
(`python benchmarks/speed.py --markdown docs/results/speed.md`).

## Defaults

Chosen by cross-validation on training data only (COIL training views; EPFL
within cars 1-10): [`DEFAULTS.md`](DEFAULTS.md), one row per value (the
studies' history: [`history/TUNING.md`](history/TUNING.md)),
[`results/tuning_coil_cv.md`](results/tuning_coil_cv.md).
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", action="store_true", help="run/resume the protocols first")
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    parser.add_argument("--results", type=Path, default=ROOT / "results")
    parser.add_argument("--jobs", type=int, default=2)
    # Every 4th frame: the published epfl-cv table's (a plain --run reproduces it).
    parser.add_argument("--epfl-cv-every", type=int, default=4,
                        help="epfl-cv tests every N-th frame (default 4, as published)")
    parser.add_argument("--protocols", default="coil-category,coil-loio,epfl-single,epfl-cv")
    args = parser.parse_args()
    protocols = [p for p in args.protocols.split(",") if p]
    walls_path = args.results / "walls.json"
    walls = json.loads(walls_path.read_text()) if walls_path.is_file() else {}
    if args.run:
        for proto in protocols:
            cmd = [sys.executable, "-m", "posevote.cli", "evaluate", proto, "--data", args.data,
                   "--out", str(args.results / proto), "--jobs", str(args.jobs)]
            if proto == "epfl-cv" and args.epfl_cv_every > 1:
                cmd += ["--every", str(args.epfl_cv_every)]
            start = time.perf_counter()
            subprocess.run(cmd, check=True)
            walls[proto] = {"seconds": time.perf_counter() - start, "jobs": args.jobs,
                            "command": " ".join(cmd[1:]).replace(sys.executable, "python")}
            args.results.mkdir(parents=True, exist_ok=True)
            walls_path.write_text(json.dumps(walls, indent=2) + "\n")
    parts = [INTRO]
    for proto in protocols:
        src = args.results / proto
        if not (src / "report.md").is_file():
            parts.append(f"\n## {proto}\n\nNot run yet: `posevote evaluate {proto} --data "
                         f"../shared/data`.\n")
            continue
        dst = DOCS / "results" / proto
        dst.mkdir(parents=True, exist_ok=True)
        for f in sorted(src.glob("*.png")) + [src / "report.md", src / "summary.json"]:
            shutil.copy2(f, dst / f.name)
        report = (src / "report.md").read_text()
        body = report.split("\n", 2)[2] if report.startswith("# ") else report
        body = body.replace("](", f"](results/{proto}/")
        wall = walls.get(proto)
        summary = json.loads((src / "summary.json").read_text())
        every = f" --every {summary['every']}" if summary.get("every", 1) > 1 else ""
        ran = [r["name"] for r in summary["rows"] if "overall" in r]
        protocol = load_protocol(proto, args.data)
        default = [r.name for r in protocol.rows if r.params is not None
                   and (not protocol.default_rows or r.name in protocol.default_rows)]
        if ran != default:
            every += " --rows " + shlex.quote(",".join(ran))
        wall_line = (f"Wall time: {wall['seconds'] / 60:.1f} min with `--jobs {wall['jobs']}` "
                     f"(`{wall['command'].replace('-m posevote.cli', 'posevote')}`).\n" if wall else
                     f"Wall time: {summary.get('wall_seconds_total', float('nan')) / 60:.1f} min "
                     f"with `--jobs {summary.get('jobs')}` (summed over resumed runs). Reproduce: "
                     f"`posevote evaluate {proto} --data ../shared/data --jobs "
                     f"{summary.get('jobs')}{every}`.\n")
        parts.append(f"\n## {proto}\n\n{wall_line}\n{body}")
    pruning = DOCS / "results" / "pruning.md"
    if pruning.is_file():
        parts.append(PRUNING + pruning.read_text()
                     + "\n![Fig. 4](results/pruning_fig4.png)\n")
        for other in sorted((DOCS / "results").glob("pruning_*.md")):
            parts.append(f"\nA larger feature budget ({other.name}):\n\n{other.read_text()}")
    parts.append(OUTRO)
    (DOCS / "RESULTS.md").write_text("".join(parts))
    print(f"wrote {DOCS / 'RESULTS.md'}")


if __name__ == "__main__":
    main()
