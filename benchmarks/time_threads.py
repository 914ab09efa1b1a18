"""Time of one estimate with 1, 2, ... threads probing viewpoints (``n_jobs``).

A robot asks for the pose of the object in one image and waits for it: what
counts there is the time of one estimate on the cores it has, not the
throughput of one process per core that the protocols measure. This script
times the same estimates with each number of threads, checks that every
thread count gives the same poses, and prints the median time per image and
the speed-up over one thread.

Cases (the settings of the benchmarks that use them):

- ``coil``: a COIL-100 instance model (views at 0, 20, ..., 340 degrees),
  clean 128x128 test views (``benchmarks/coil_instance.py``);
- ``clutter``: the same model on test views pasted on 256x256 clutter, 20%
  hidden, with the ``cluttered`` preset (its search and local
  refinement;
- ``epfl``: an EPFL car's instance model (40 evenly spaced frames of car 2,
  the ``turntable`` preset) on full 376x250 frames of the same car.

Usage::

    python benchmarks/time_threads.py [--data ../shared/data] [--threads 1,2]
        [--cases coil,clutter,epfl] [--images 12] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from posevote import PoseEstimator
from posevote.data import read_coil, read_epfl
from posevote.evaluation.synthetic import paste_on_clutter

COIL_OBJECT = 6
EPFL_CAR = 2


def coil_case(data: Path, n_images: int, clutter: bool
              ) -> tuple[PoseEstimator, list[np.ndarray]]:
    """A COIL instance model and its test images, clean or pasted on clutter."""
    folder = data / "coil-100"
    train = read_coil(folder, objects=[COIL_OBJECT], azimuths_deg=range(0, 360, 20))
    other = [a for a in range(0, 360, 5) if a % 20]
    test = read_coil(folder, objects=[COIL_OBJECT],
                     azimuths_deg=other[::max(1, len(other) // n_images)][:n_images])
    est = PoseEstimator.from_preset("cluttered" if clutter else "default")
    est.fit(train.load_images(), train.poses, boxes=train.boxes)
    images = test.load_images()
    if clutter:
        rng = np.random.default_rng(0)
        images = [paste_on_clutter(im, box, rng=rng).image
                  for im, box in zip(images, test.boxes, strict=True)]
    return est, images


def epfl_case(data: Path, n_images: int) -> tuple[PoseEstimator, list[np.ndarray]]:
    """Car 2's 40-frame instance model and other frames of its sequence."""
    from posevote.data import read_image

    seq = read_epfl(data / "epfl-gims08" / "tripod-seq", cars=[EPFL_CAR])
    n = len(seq.images)
    chosen = sorted(set(np.linspace(0, n, 40, endpoint=False).round().astype(int).tolist()))
    rest = [i for i in range(n) if i not in chosen]
    test = rest[::max(1, len(rest) // n_images)][:n_images]
    est = PoseEstimator.from_preset("turntable").fit([seq.images[i] for i in chosen],
                                                  seq.poses[chosen], boxes=seq.boxes[chosen])
    return est, [read_image(seq.images[i]) for i in test]


def time_case(est: PoseEstimator, images: list[np.ndarray], threads: list[int]
              ) -> dict[int, float]:
    """Median seconds per estimate for each thread count; the poses must agree."""
    est.set_params(n_jobs=1).estimate(images[0])  # compile before timing
    times: dict[int, float] = {}
    reference = None
    for n in threads:
        est.set_params(n_jobs=n)
        secs, poses = [], []
        for img in images:
            t0 = time.perf_counter()
            result = est.estimate(img)
            secs.append(time.perf_counter() - t0)
            poses.append(result.modes)
        if reference is None:
            reference = poses
        elif poses != reference:
            raise RuntimeError(f"{n} threads gave other poses than {threads[0]}")
        times[n] = float(np.median(secs))
    return times


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path,
                        default=Path(__file__).resolve().parents[2] / "shared" / "data")
    parser.add_argument("--threads", default="1,2")
    parser.add_argument("--cases", default="coil,clutter,epfl")
    parser.add_argument("--images", type=int, default=12)
    parser.add_argument("--markdown", type=Path)
    args = parser.parse_args(argv)
    threads = [int(t) for t in args.threads.split(",")]
    if not threads or min(threads) < 1:
        parser.error("--threads: comma-separated counts >= 1")
    builders = {"coil": lambda: coil_case(args.data, args.images, clutter=False),
                "clutter": lambda: coil_case(args.data, args.images, clutter=True),
                "epfl": lambda: epfl_case(args.data, args.images)}
    cases = [c.strip() for c in args.cases.split(",")]
    for c in cases:
        if c not in builders:
            parser.error(f"unknown case {c!r}; cases: {', '.join(builders)}")
    lines = ["```", "$ python " + " ".join(shlex.quote(a) for a in sys.argv),
             f"{os.cpu_count()} cores, {platform.python_implementation()} "
             f"{platform.python_version()}; median seconds per estimate "
             f"({args.images} images per case)",
             f"{'case':10s}" + "".join(f"{f'{n} thr':>10s}" for n in threads)
             + "".join(f"{f'x{n}':>8s}" for n in threads[1:])]
    print("\n".join(lines[1:]), flush=True)
    for case in cases:
        est, images = builders[case]()
        times = time_case(est, images, threads)
        line = (f"{case:10s}" + "".join(f"{times[n]:10.3f}" for n in threads)
                + "".join(f"{times[threads[0]] / times[n]:8.2f}" for n in threads[1:]))
        print(line, flush=True)
        lines.append(line)
    lines.append("```")
    if args.markdown:
        tmp = args.markdown.with_suffix(args.markdown.suffix + ".tmp")
        tmp.write_text("\n".join(lines) + "\n")
        tmp.replace(args.markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
