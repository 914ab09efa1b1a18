"""The rendered capture check (``posevote evaluate rendered-capture``) over several seeds.

Each seed renders its own photographs of the object on the board and its own
test images (:mod:`posevote.evaluation.capture_check`); the table gives each
seed's capture figures and the two models' rotation errors, then the tests of
every seed pooled.

Usage::

    python benchmarks/capture_check.py [--seeds 0 1 2] [--photos 36] [--tests 48]
        [--out DIR] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from _markdown import emit  # noqa: E402

from posevote.evaluation.capture_check import CaptureSetup, run_capture_check  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--photos", type=int, default=36)
    ap.add_argument("--tests", type=int, default=48)
    ap.add_argument("--out", help="results folder, one sub-folder per seed (default: temporary)")
    ap.add_argument("--markdown", help="also write the report here")
    args = ap.parse_args(argv)
    rows, pooled = [], {"captured": [], "true": []}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            s = run_capture_check(CaptureSetup(photos=args.photos, tests=args.tests, seed=seed),
                                  Path(args.out or tmp) / f"seed{seed}",
                                  log=lambda m: print(m, file=sys.stderr))
            i, m = s["intrinsics_error_pct"], s["models"]
            rows.append(
                f"| {seed} | {s['kept']}/{s['photos']} | {s['calibration_rms_px']:.3f} | "
                f"{max(i.values()):.2f} | {s['rotation_deg']['median']:.2f} / "
                f"{s['rotation_deg']['max']:.2f} | {s['distance_pct']['max']:.2f} | "
                f"{s['box_iou']['median']:.3f} / {s['box_iou']['min']:.3f} | "
                f"{s['mask_iou']['median']:.3f} / {s['mask_iou']['min']:.3f} | "
                f"{m['captured']['median_deg']:.1f} / {m['captured']['mean_deg']:.1f} | "
                f"{m['true']['median_deg']:.1f} / {m['true']['mean_deg']:.1f} |")
            for name in pooled:
                pooled[name] += s["errors_deg"][name]
    lines = [f"Rendered capture check: {args.photos} photographs of the duck on the board per "
             f"seed, {args.tests} test renders off the board per seed, `cluttered` preset.", "",
             "| seed | kept | calib. RMS px | worst fx/fy/cx/cy % | rotation median / max deg "
             "| distance max % | box IoU median / min | mask IoU median / min "
             "| captured model median / mean deg | true model median / mean deg |",
             "|---|---|---|---|---|---|---|---|---|---|", *rows, "",
             f"All {len(pooled['true'])} tests pooled:", "",
             "| trained on | median deg | mean deg | < 30 deg |", "|---|---|---|---|"]
    for name, errors in pooled.items():
        e = np.array(errors)
        lines.append(f"| {name} | {np.median(e):.2f} | {e.mean():.2f} | "
                     f"{100 * np.mean(e < 30):.0f}% |")
    c, t = np.array(pooled["captured"]), np.array(pooled["true"])
    lines += ["", f"Captured over true: median {np.median(c) / np.median(t):.2f}x, mean "
              f"{c.mean() / t.mean():.2f}x.", ""]
    return emit("\n".join(lines), args.markdown, __file__, argv, fenced=False)


if __name__ == "__main__":
    sys.exit(main())
