"""Textured objects over the whole viewing sphere, in clutter: the development set of issue 66.

Each object of :data:`OBJECTS` (textured meshes of ``pybullet_data``: the jenga
block, whose printed words and numbers alone tell its sides apart, and the
rubber duck with pybullet's UV test image laid over it) is run through the
rendered-sphere protocol (:mod:`posevote.evaluation.sphere`) with each view
set of :data:`VIEW_SETS`: 72 training views (azimuth every 20 degrees at four
elevations 25 degrees apart) and 468 (every 10 degrees at thirteen), tested
in clutter with the ``cluttered`` preset. Each ``--setting`` (a
space-separated list of ``NAME=VALUE``; none: the preset as it is) is a row
of the table, per object and view set.

Usage::

    python benchmarks/textured_sphere.py [--images 40] [--views 72,468] [--jobs 2]
        [--setting "refine.keypoints=False" --setting "refine.keypoints=True"]
        [--markdown FILE]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from _markdown import emit  # noqa: E402
from _settings import parse_settings  # noqa: E402

from posevote.evaluation.sphere import ELEVATIONS_DEG, SphereSetup, run_sphere  # noqa: E402

#: The textured objects: (mesh of pybullet_data, image laid over it or None).
OBJECTS = (("jenga/jenga.urdf", None), ("duck_vhacd.urdf", "uvmap.png"))
#: Training views: their number -> (azimuth step, elevations), degrees.
VIEW_SETS = {72: (20.0, (-20.0, 5.0, 30.0, 55.0)), 468: (10.0, ELEVATIONS_DEG)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--images", type=int, default=40)
    ap.add_argument("--views", default="72,468", help="view sets, of " +
                    ", ".join(str(v) for v in VIEW_SETS))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--setting", action="append", default=[],
                    help="a row: space-separated NAME=VALUE estimator settings")
    ap.add_argument("--markdown", help="also write the report here")
    args = ap.parse_args(argv)
    views = [int(v) for v in args.views.split(",")]
    unknown = [v for v in views if v not in VIEW_SETS]
    if unknown:
        ap.error(f"--views: no view set of {unknown} views (there are {sorted(VIEW_SETS)})")
    rows = args.setting or [""]
    lines = ["| object | training views | settings | rotation median ° | rotation mean ° "
             "| % < 10° | % < 30° | flips % | elevation median ° | detected % | s / image |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for mesh, texture in OBJECTS:
        for n_views in views:
            step, elevations = VIEW_SETS[n_views]
            for row in rows:
                setup = SphereSetup(mesh=mesh, texture=texture, azimuth_step_deg=step,
                                    elevations_deg=elevations, n_images=args.images,
                                    seed=args.seed, params=parse_settings(row.split()))
                print(f"{setup.name}, {n_views} views, {row or 'as the preset'}",
                      file=sys.stderr)
                with tempfile.TemporaryDirectory() as tmp:
                    s = run_sphere(setup, tmp, jobs=args.jobs)
                lines.append(
                    f"| {setup.name} | {n_views} | {row or 'preset'} | "
                    f"{s['rotation_median_deg']:.2f} | {s['rotation_mean_deg']:.2f} | "
                    f"{s['rotation_under_10_pct']:.1f} | {s['rotation_under_30_pct']:.1f} | "
                    f"{s['flip_rate_pct']:.1f} | {s['elevation_median_deg']:.2f} | "
                    f"{s['detected_pct']:.1f} | {s['seconds_median']:.2f} |")
    text = ("# Textured objects over the sphere, in clutter (`cluttered` preset, "
            f"{args.images} test images each, seed {args.seed})\n\n"
            "Test views at random azimuths and elevations between the extreme training "
            "elevations, pasted on 256 x 256 clutter at 0.8-1.25 times the training size, "
            "in-plane within 30 degrees, 20% hidden; errors as the rendered-sphere "
            "protocol's (a missed image counts 180 degrees of rotation).\n\n"
            + "\n".join(lines) + "\n")
    return emit(text, args.markdown, __file__, argv, fenced=False)


if __name__ == "__main__":
    sys.exit(main())
