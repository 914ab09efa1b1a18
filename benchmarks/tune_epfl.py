"""Settings sweeps for the EPFL protocols, on development data only.

``--protocol epfl-cv`` (default) runs the preset row (``--row paper``: the
paper's row, edges alone) of ``posevote evaluate epfl-cv`` (five folds,
each testing two cars on a model of the other eight; full frames;
``--folds 2`` is the split 1-5 <-> 6-10 the ``category`` preset was first
chosen on) and prints each fold's % under 45 degrees and detection rate.
``--protocol epfl-single`` runs the protocol of Fig. 6 (15, 30 and 40
evenly spaced training frames, one instance model per car, the other
frames tested) on cars 2-10 instead of car 1, which the protocol reports
on: this is how the ``turntable`` preset was chosen.

Both go through the same runner as ``posevote evaluate``, on every
``--every``-th test frame, with the protocol's preset plus the settings given
(``group.field=VALUE``, e.g. ``kernel.position_sigma=6.0`` or ``appearance=None``), and
print one line per setting: median, mean, % under 45 degrees, detection
rate, seconds per frame (and, for epfl-single, the median and mean of each
training-set size). Cars 11-20 (the held-out test set) are never read.
Results are in docs/DEFAULTS.md.

Usage::

    python benchmarks/tune_epfl.py [--protocol epfl-cv|epfl-single] [--cars 2,3,...]
        [--every 8] [--setting "search.density_cap=0.5 kernel.position_sigma=6.0" ...] [--keep DIR]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from _settings import parse_settings  # noqa: E402

from posevote.evaluation.protocols import Row, epfl_cv, epfl_single  # noqa: E402
from posevote.evaluation.runner import run_protocol  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared"
                                              / "data"))
    parser.add_argument("--protocol", choices=("epfl-cv", "epfl-single"), default="epfl-cv")
    parser.add_argument("--cars", default=None,
                        help="comma-separated cars (default: 1-10 for epfl-cv, 2-10 for "
                             "epfl-single)")
    parser.add_argument("--every", type=int, default=8)
    parser.add_argument("--folds", type=int, default=5, help="epfl-cv folds (default 5)")
    parser.add_argument("--row", choices=("preset", "paper"), default="preset",
                        help="start from the preset's row or the paper's (edges alone)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--keep", type=Path, default=None,
                        help="keep each setting's results folder as KEEP/0, KEEP/1, ... "
                             "(records, models, report) instead of discarding it")
    parser.add_argument("--setting", action="append", default=[],
                        help="space-separated NAME=VALUE items; one line per --setting "
                             "(none: the protocol's preset row as it is)")
    args = parser.parse_args(argv)
    if args.cars:
        cars = [int(c) for c in args.cars.split(",")]
    else:
        cars = list(range(1 if args.protocol == "epfl-cv" else 2, 11))
    if args.protocol == "epfl-single" and 1 in cars:
        parser.error("car 1 is the epfl-single protocol's test car; develop on cars 2-10")
    builder = epfl_cv if args.protocol == "epfl-cv" else epfl_single
    base = builder(args.data, cars=cars, **({"folds": args.folds}
                                            if args.protocol == "epfl-cv" else {}))
    main = next(r for r in base.rows if r.name == base.main_row) if args.row == "preset" \
        else next(r for r in base.rows if r.name.startswith("paper"))
    row_name = "setting"  # the settings below decide what it runs
    for k, text in enumerate(args.setting or [""]):
        overrides = parse_settings(text.split())
        protocol = dataclasses.replace(base, rows=(Row(name=row_name,
                                                       params={**main.params, **overrides}),))
        start = time.perf_counter()
        with contextlib.ExitStack() as stack:
            out = (args.keep / str(k) if args.keep is not None
                   else stack.enter_context(tempfile.TemporaryDirectory()))
            summary = run_protocol(protocol, out, jobs=args.jobs, every=args.every,
                                   rows=[row_name],
                                   log=lambda _msg: None)
        row = next(r for r in summary["rows"] if r["name"] == row_name)
        m = row["overall"]
        groups = ""
        if args.protocol == "epfl-single":
            groups = " | " + ", ".join(
                f"{name.split()[0]}: {g['median']:.2f}/{g['mean']:.2f}"
                for name, g in sorted(row["groups"].items(), key=lambda kv: int(kv[0].split()[0])))
        folds = ""
        if args.protocol == "epfl-cv":
            folds = " | folds <45: " + " ".join(f"{f['under_45']:.0f}"
                                                for f in row["splits"].values()) \
                + " found: " + " ".join(f"{f['detection_rate']:.0f}"
                                         for f in row["splits"].values())
        print(f"{args.row} {overrides or base.preset}: n={m['n']} median {m['median']:.2f} "
              f"mean {m['mean']:.1f} <45 {m['under_45']:.1f}% flips {m['flip_rate']:.1f}% "
              f"detected {m['detection_rate']:.1f}% s/img {m['median_seconds']:.2f} "
              f"wall {time.perf_counter() - start:.0f} s{groups}{folds}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
