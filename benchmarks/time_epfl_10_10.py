"""Wall time of ``posevote evaluate epfl-10-10`` on this machine, without cars 11-20.

Issue 3 asks the epfl-10-10 protocol to finish within 15 minutes with
``--jobs 2``. Its test set (cars 11-20, 1120 frames) is held out and not in
``../shared``, so this script times the same pipeline on stand-ins: it
trains each row's model exactly as the protocol does (cars 1-10, every
frame, the ``category`` preset) and estimates every ``--every``-th frame of
cars 1-10 (the same camera, image size and kind of scene) through the same
runner, then projects the protocol's wall time as training time plus the
test time scaled to 1120 frames. The stand-ins are training frames, so the
pose errors of this run mean nothing and are not printed; only time is.

Usage::

    python benchmarks/time_epfl_10_10.py [--data ../shared/data] [--every 8] [--jobs 2]
        [--rows "weights + fitting,..."] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from _markdown import emit  # noqa: E402

from posevote.data import read_epfl  # noqa: E402
from posevote.evaluation.protocols import (  # noqa: E402
    _EPFL_10_10_DEFAULT_ROWS,
    _EPFL_ROWS,
    Protocol,
    Split,
    _epfl_folder,
)
from posevote.evaluation.runner import run_protocol  # noqa: E402

#: Test frames of the held-out protocol (cars 11-20), from METHOD.md.
PROTOCOL_TEST_FRAMES = 1120


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    ap.add_argument("--every", type=int, default=8, help="time every N-th stand-in frame")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--rows", default=",".join(_EPFL_10_10_DEFAULT_ROWS),
                    help="comma-separated rows (default: the protocol's default rows)")
    ap.add_argument("--markdown", help="also write the printed report here")
    args = ap.parse_args(argv)
    rows = [r.strip() for r in args.rows.split(",")]
    known = {r.name for r in _EPFL_ROWS}
    if unknown := [r for r in rows if r not in known]:
        ap.error(f"unknown row(s) {unknown}; rows: {', '.join(sorted(known))}")
    folder = _epfl_folder(args.data)
    cars = read_epfl(folder, cars=list(range(1, 11)))
    protocol = Protocol(
        name="epfl-10-10-timing",
        description="epfl-10-10's training; cars 1-10 frames as timing stand-ins",
        splits=(Split(name="cars01-10_timing", train=cars, test=cars,
                      groups=tuple(cars.instances)),),
        rows=_EPFL_ROWS, preset="category")
    lines = []
    total = 0.0
    for row in rows:
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            summary = run_protocol(protocol, tmp, jobs=args.jobs, every=args.every, rows=[row],
                                   log=lambda _msg: None)
            wall = time.perf_counter() - start
        entry = summary["rows"][0]
        train = float(next(iter(entry["models"].values()))["train_seconds"])
        n = len(range(0, len(cars.images), args.every))
        test = wall - train
        projected = train + test * PROTOCOL_TEST_FRAMES / n
        total += projected
        lines.append(f"{row[:40]:<42}{train:>9.1f}{n:>8d}{test:>9.1f}{test * args.jobs / n:>10.2f}"
                     f"{projected / 60:>11.1f}")
    report = io.StringIO()
    with contextlib.redirect_stdout(report):
        print(f"epfl-10-10 wall time, projected from cars 1-10 stand-ins (every {args.every}th "
              f"frame), --jobs {args.jobs}, {os.cpu_count()} cores")
        print(f"{'row':<42}{'train s':>9}{'frames':>8}{'test s':>9}{'s/frame':>10}"
              f"{'proj. min':>11}")
        print("\n".join(lines))
        print(f"all rows: {total / 60:.1f} min projected for {PROTOCOL_TEST_FRAMES} test frames "
              "(s/frame is per process)")
    return emit(report.getvalue(), args.markdown, __file__, argv)


if __name__ == "__main__":
    raise SystemExit(main())
