"""Variants of the rendered-sphere protocol (``posevote evaluate rendered-sphere``).

The protocol itself is :mod:`posevote.evaluation.sphere`; this script runs it
with the settings the command line does not offer: another mesh, other
training elevations (a turntable of the same object, to tell the sphere from
the clutter), the views tested as rendered on black (``--clean``, the
``default`` preset), the test depths told to the estimator
(``--known-depths``, as ``posevote estimate --depth-range`` does), or
estimator overrides. The results folder gets the
protocol's files; ``--markdown`` also writes its report under the command
line that made it.

Usage::

    python benchmarks/rendered_sphere.py [--mesh r2d2.urdf] [--texture uvmap.png]
        [--azimuth-step 10] [--images 40] [--clean]
        [--elevations -30,-15,...] [--known-depths] [--jobs 2] [--param NAME=VALUE ...] [--out DIR]
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

from posevote.evaluation.sphere import (  # noqa: E402
    AZIMUTH_STEP_DEG,
    ELEVATIONS_DEG,
    MESHES,
    SphereSetup,
    report_text,
    run_sphere,
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mesh", default="r2d2.urdf", choices=sorted(MESHES))
    ap.add_argument("--texture", help="an image of pybullet_data laid over the mesh")
    ap.add_argument("--azimuth-step", type=float, default=AZIMUTH_STEP_DEG,
                    help="training azimuths' step, degrees")
    ap.add_argument("--images", type=int, default=40)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--elevations", default=",".join(f"{e:g}" for e in ELEVATIONS_DEG),
                    help="training elevations, degrees (tests drawn between the extremes)")
    ap.add_argument("--clean", action="store_true",
                    help="test views as rendered, on black (the default preset): the sphere "
                         "model without clutter")
    ap.add_argument("--known-depths", action="store_true",
                    help="tell the estimator the test depths (the scales searched from them)")
    ap.add_argument("--param", action="append", default=[], help="NAME=VALUE estimator setting")
    ap.add_argument("--out", help="results folder (default: a temporary one)")
    ap.add_argument("--markdown", help="also write the report here")
    args = ap.parse_args(argv)
    setup = SphereSetup(mesh=args.mesh, n_images=args.images, seed=args.seed,
                        elevations_deg=tuple(float(e) for e in args.elevations.split(",")),
                        clean=args.clean, params=parse_settings(args.param),
                        known_depths=args.known_depths, texture=args.texture,
                        azimuth_step_deg=args.azimuth_step)
    with tempfile.TemporaryDirectory() as tmp:
        summary = run_sphere(setup, args.out or tmp, jobs=args.jobs,
                             log=lambda m: print(m, file=sys.stderr))
    text = report_text(setup, summary, summary["n_training_views"])
    text += f"\nWall time {summary['wall_seconds']:.0f} s with {args.jobs} processes.\n"
    return emit(text, args.markdown, __file__, argv, fenced=False)


if __name__ == "__main__":
    sys.exit(main())
