"""Cold-start wall time of the command line, against ``python -c pass``.

Trains a COIL-100 instance model (object 6, every 20 degrees) into a
temporary folder, runs one ``posevote estimate`` to fill numba's on-disk
cache of compiled kernels, then times fresh processes, alternating:
``python -c pass``, ``posevote --help`` and ``posevote estimate MODEL IMAGE``.
Prints the median wall time of each and the difference to ``python -c pass``.

Usage::

    python benchmarks/cli_startup.py [--data ../shared/data] [--runs 7]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _wall(cmd: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run(cmd, check=False, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args(argv)
    cli = [sys.executable, "-m", "posevote.cli"]
    image = str(Path(args.data) / "coil-100" / "obj6__45.png")
    with tempfile.TemporaryDirectory() as tmp:
        model = str(Path(tmp) / "car6.npz")
        subprocess.run([*cli, "train", str(Path(args.data) / "coil-100"), "--layout", "coil",
                        "--objects", "6", "--azimuth-step-deg", "20", "-o", model], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        commands = {"python -c pass": [sys.executable, "-c", "pass"],
                    "posevote --help": [*cli, "--help"],
                    "posevote estimate (COIL instance model)": [*cli, "estimate", model, image]}
        _wall(commands["posevote estimate (COIL instance model)"])  # fills numba's cache
        times: dict[str, list[float]] = {name: [] for name in commands}
        for _ in range(args.runs):
            for name, cmd in commands.items():
                times[name].append(_wall(cmd))
    base = statistics.median(times["python -c pass"])
    print(f"median wall of {args.runs} fresh processes each (alternating), {sys.executable}")
    for name, values in times.items():
        median = statistics.median(values)
        print(f"{name:<42}{median:8.3f} s   {median - base:+8.3f} s against python -c pass")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
