"""Settings sweep for the EPFL category protocols, on epfl-cv (cars 1-10 only).

Runs the "weights + fitting" row of ``posevote evaluate epfl-cv`` (cars
1-5 train / 6-10 test, then the other way round; full frames) on every
``--every``-th test frame, through the same runner, with ``EPFL_PARAMS``
plus the settings given, and prints one line per setting: median, mean, %
under 45 degrees, detection rate, seconds per frame. Cars 11-20 (the
held-out test set) are never read. This is how ``EPFL_CATEGORY_PARAMS``
was chosen (docs/TUNING.md).

Usage::

    python benchmarks/tune_epfl_cv.py [--every 8] [--setting "density_cap=0.5 position_sigma=6.0" ...]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from _settings import parse_settings  # noqa: E402

from posevote.evaluation.protocols import EPFL_PARAMS, load_protocol  # noqa: E402
from posevote.evaluation.runner import run_protocol  # noqa: E402

ROW = "weights + fitting"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared"
                                              / "data"))
    parser.add_argument("--every", type=int, default=8)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--setting", action="append", default=[],
                        help="space-separated NAME=VALUE items; one line per --setting "
                             "(none: EPFL_PARAMS alone)")
    args = parser.parse_args(argv)
    base = load_protocol("epfl-cv", args.data)
    for text in args.setting or [""]:
        overrides = parse_settings(text.split())
        protocol = dataclasses.replace(base, base_params={**EPFL_PARAMS, **overrides})
        start = time.perf_counter()
        with tempfile.TemporaryDirectory() as out:
            summary = run_protocol(protocol, out, jobs=args.jobs, every=args.every, rows=[ROW],
                                   log=lambda _msg: None)
        m = next(r for r in summary["rows"] if r["name"] == ROW)["overall"]
        print(f"{overrides or 'EPFL_PARAMS'}: n={m['n']} median {m['median']:.1f} "
              f"mean {m['mean']:.1f} <45 {m['under_45']:.1f}% "
              f"detected {m['detection_rate']:.1f}% s/img {m['median_seconds']:.2f} "
              f"wall {time.perf_counter() - start:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
