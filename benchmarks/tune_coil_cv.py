"""Choose estimator defaults by cross-validation on COIL-100 *training* views.

Each setting is scored with ``coil_instance.py --cv``: 3 folds over the 18
protocol training views (0, 20, ..., 340 degrees) of the 16 objects; the
protocol's 54 test views per object are never looked at. One parameter is
varied at a time around the current defaults; the table is printed and the
choice is recorded by hand in ``docs/DEFAULTS.md`` and the estimator defaults.

Usage::

    python benchmarks/tune_coil_cv.py [--data ../shared/data/coil-100] [--jobs 2]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import coil_instance  # noqa: E402

# The settings of the default preset that this study chose. (It also chose
# the constants ORIENTATION_KAPPA = 8 over 4 and K1_CUTOFF = 0.1 over 0.05,
# and rejected the clutter weighting: docs/results/tuning_coil_cv.md.)
GRID = {
    "kernel.position_sigma": [2.0, 3.0, 4.0],
    "search.viewpoint_subdivisions": [1, 2],
}
ROW = "weights + fitting"


def score(params: dict, data: str, jobs: int) -> tuple[float, float, float]:
    argv = ["--cv", "--data", data, "--jobs", str(jobs), "--rows", ROW]
    for name, value in params.items():
        argv += ["--param", f"{name}={value!r}"]
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        coil_instance.main(argv)
    line = next(ln for ln in out.getvalue().splitlines() if ln.startswith(ROW))
    median, mean, _, _, ms = (float(x.rstrip("%")) for x in re.split(r"\s+", line[20:].strip()))
    return median, mean, ms


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[1].parent
                                          / "shared/data/coil-100"))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--markdown", help="also write the table here (markdown code block)")
    args = ap.parse_args()
    lines = [f"3-fold CV on COIL-100 training views, row '{ROW}'; one parameter varied at a time, "
             "the others at their defaults",
             f"{'setting':<32}{'median':>8}{'mean':>8}{'ms/img':>8}"]
    for line in lines:
        print(line)
    t0 = time.perf_counter()
    for name, values in GRID.items():
        for value in values:
            med, mean, ms = score({name: value}, args.data, args.jobs)
            lines.append(f"{name + '=' + repr(value):<32}{med:>8.2f}{mean:>8.2f}{ms:>8.1f}")
            print(lines[-1], flush=True)
    lines.append(f"wall {time.perf_counter() - t0:.0f} s")
    print(lines[-1])
    if args.markdown:
        from posevote._io import atomic_write_text

        atomic_write_text(args.markdown, "```\n$ python benchmarks/tune_coil_cv.py\n"
                          + "\n".join(lines) + "\n```\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
