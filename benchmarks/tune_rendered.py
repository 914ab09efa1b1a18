"""Precision development set: rendered turntables with the COIL protocol's geometry.

The COIL cross-validation (``coil_instance.py --cv``) can only hold out
training views, which lie 20 degrees from their neighbours once one in three
is held out; the protocol's test views lie 5, 10 and 15 degrees from a
training view. What the continuous refinement does at those offsets (in
particular whether it pulls estimates toward the probed training views) is
measured here instead, on meshes that ship inside the ``pybullet`` wheel,
none of them a COIL object: each is rendered on black at 5-degree steps
(``posevote.evaluation.rendering.render_turntable``, 128 x 128 pixels, camera elevation 20
degrees), an instance model is trained on 0, 20, ..., 340 degrees and the
other 54 views are estimated, exactly the COIL instance protocol.

``--clutter`` pastes every test view on clutter as the cluttered COIL
benchmark does (random position, scale 0.7-1.3, in-plane rotation +-30
degrees, 20% occluded; seeded per object) and searches with that
benchmark's settings (the ``cluttered`` preset's search):
the precision of the cluttered protocol at its own offsets, which the
clutter self-test (true poses at training views) cannot measure. It also prints the % of positions
within 5 px and of errors over 30 degrees.

Printed per setting: median, mean and 90th percentile of the absolute
azimuth error, % under 5 degrees, and for each offset from the nearest
training view the median absolute error and the median *pull*: the signed
error toward the nearest training view (positive: the estimate moved toward
it; 0 at the 10-degree offset, which is halfway). Errors over 20 degrees
(front/back confusions) are left out of the pull.

With ``--clutter`` a second line gives, of the poses within 10 degrees, the
% of positions within 5 px and the median in-plane error and |log scale|
error of those more than 5 px off: whether the positions miss where the
pose misses or where the alignment does. ``--records FILE`` writes one JSON
line per test view and setting (signed azimuth error, position offset,
in-plane error, estimated and true scale) for analyses of one's own.

Usage::

    python benchmarks/tune_rendered.py [--clutter] [--setting "kernel.position_sigma=2.5" ...] [--jobs 2]
        [--markdown docs/results/tuning_rendered.md] [--records records.jsonl]
"""

from __future__ import annotations

import argparse
import io
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from _markdown import write_markdown  # noqa: E402
from _settings import parse_settings  # noqa: E402

from posevote import PoseEstimator  # noqa: E402
from posevote._io import atomic_write_text  # noqa: E402
from posevote.evaluation.rendering import render_turntable  # noqa: E402
from posevote.evaluation.synthetic import paste_on_clutter  # noqa: E402
from posevote.geometry import angle_difference  # noqa: E402
from posevote.refinement import RefineOptions  # noqa: E402

#: (name, URDF in pybullet_data, rest orientation). The four named models and
#: six of pybullet's random shapes, picked for having no rotational symmetry.
OBJECTS = (
    ("duck", "duck_vhacd.urdf", (np.pi / 2, 0.0, 0.0)),
    ("teddy", "teddy_vhacd.urdf", (np.pi / 2, 0.0, 0.0)),
    ("racecar", "racecar/racecar.urdf", (0.0, 0.0, 0.0)),
    ("r2d2", "r2d2.urdf", (0.0, 0.0, 0.0)),
    *((f"random {i}", f"random_urdfs/{i}/{i}.urdf", (0.0, 0.0, 0.0))
      for i in ("002", "005", "010", "020", "030", "040")),
)
STEP_DEG = 5
TRAIN_EVERY = 4  # every 20 degrees, as the COIL protocol


def run_object(obj: tuple[str, str, tuple[float, float, float]], params: dict, clutter: bool,
               seed: int) -> dict:
    """Train on every 20 degrees of one rendered object, estimate the other views."""
    name, mesh, euler = obj
    azimuths = np.radians(np.arange(0, 360, STEP_DEG))
    views = render_turntable(azimuths, mesh=mesh, base_euler=euler, distance=None)
    train = views[::TRAIN_EVERY]
    # In clutter: the cluttered preset's search and re-ranking; its local refinement (and the
    # steps that go with it) only if asked for.
    base = ("cluttered", {"refine": RefineOptions(), "templates__half_turn": False}) if clutter \
        else ("default", {})
    base[1]["min_score"] = 0.0   # the object is in every test image
    estimator = PoseEstimator.from_preset(base[0], **{**base[1], **params}).fit(
        [v.image for v in train], [v.azimuth for v in train], boxes=[v.box for v in train],
        masks=[v.mask for v in train])
    rng = np.random.default_rng([seed, OBJECTS.index(obj)])
    signed, offsets, seconds, pos_err, records = [], [], [], [], []
    for k, view in enumerate(views):
        if k % TRAIN_EVERY == 0:
            continue
        image, truth = view.image, None
        if clutter:
            pasted = paste_on_clutter(view.image, view.box, rng=rng, mask=view.mask)
            image, truth = pasted.image, np.asarray(pasted.position)
        result = estimator.estimate(image)
        best = result.best
        est = best.azimuth if best is not None else view.azimuth + np.pi
        signed.append(float(np.degrees(np.angle(np.exp(1j * (est - view.azimuth))))))
        offsets.append(k % TRAIN_EVERY)
        seconds.append(result.seconds)
        record = {"object": name, "azimuth_deg": STEP_DEG * k, "error_deg": signed[-1]}
        if truth is not None and best is not None:
            dx, dy = (np.asarray(best.position) - truth).tolist()
            pos_err.append(float(np.hypot(dx, dy)))
            record |= {"dx_px": dx, "dy_px": dy, "inplane_error_deg": float(np.degrees(
                angle_difference(best.inplane, pasted.inplane))),
                "scale": best.scale, "true_scale": pasted.scale}
        elif truth is not None:
            pos_err.append(np.inf)
        records.append(record)
    return {"name": name, "signed": signed, "offsets": offsets, "seconds": seconds,
            "position_error_px": pos_err, "records": records}


def report(results: list[dict]) -> str:
    """One line: overall errors, then median |error| and pull at each offset."""
    signed = np.concatenate([r["signed"] for r in results])
    offsets = np.concatenate([r["offsets"] for r in results])
    err = np.abs(signed)
    # toward the nearest training view: it lies below the truth for offsets 1,
    # above for offsets 3 (in steps of STEP_DEG)
    toward = np.where(offsets == 1, -signed, np.where(offsets == 3, signed, 0.0))
    parts = [f"{np.median(err):6.2f} {np.mean(err):6.2f} {np.percentile(err, 90):6.2f} "
             f"{100 * np.mean(err < 5):5.1f}%"]
    for off in (1, 2, 3):
        sel = offsets == off
        pull = toward[sel & (err < 20)]
        parts.append(f"{np.median(err[sel]):5.2f} {np.median(pull) if off != 2 else 0.0:+5.2f}")
    ms = 1000 * np.median(np.concatenate([r["seconds"] for r in results]))
    parts.append(f"{ms:6.1f}")
    positions = np.concatenate([r["position_error_px"] for r in results])
    if positions.size:
        near = err <= 30
        parts.append(f"{100 * np.mean(positions <= 5):5.1f}% {100 * np.mean(err > 30):5.1f}% "
                     f"{100 * np.mean(positions[near] <= 5):5.1f}%")
    per_object = ", ".join(f"{r['name']}: {np.median(np.abs(r['signed'])):.2f}" for r in results)
    return "  ".join(parts) + _alignment_line(results) + f"\n    per object median: {per_object}\n"


def _alignment_line(results: list[dict]) -> str:
    """Of the poses within 10 degrees: positions within 5 px, and how the others are off."""
    recs = [r for res in results for r in res["records"] if "dx_px" in r]
    if not recs:
        return ""
    close = [r for r in recs if abs(r["error_deg"]) < 10]
    missed = [r for r in close if np.hypot(r["dx_px"], r["dy_px"]) > 5]
    line = (f"\n    of the {len(close)} poses within 10 deg: "
            f"{100 * (1 - len(missed) / max(len(close), 1)):.1f}% within 5 px")
    if missed:
        inplane = np.median([abs(r["inplane_error_deg"]) for r in missed])
        log_scale = np.median([abs(np.log(r["scale"] / r["true_scale"])) for r in missed])
        line += (f"; the {len(missed)} others: median in-plane error {inplane:.1f} deg, "
                 f"|log scale| error {log_scale:.3f}")
    return line


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--setting", action="append", default=[],
                    help="space-separated NAME=VALUE estimator settings; one line per --setting")
    ap.add_argument("--clutter", action="store_true",
                    help="paste the test views on clutter (cluttered COIL protocol)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--markdown", help="also write the printed report here, as a markdown file")
    ap.add_argument("--records", help="write one JSON line per test view and setting here")
    args = ap.parse_args(argv)
    records: list[str] = []
    out = io.StringIO()
    out.write(f"rendered turntables, {len(OBJECTS)} objects, train 0:20:340, test the other 54"
              f"{' pasted on clutter' if args.clutter else ''}\n")
    out.write("setting: median mean p90 <5deg | offset 5: median pull | 10: median | "
              "15: median pull | ms/img" + (" | pos<=5px >30deg pos<=5px-of-those-within-30deg"
                                          if args.clutter else "") + "\n")
    print(out.getvalue(), end="", flush=True)
    t0 = time.perf_counter()
    for text in args.setting or [""]:
        params = parse_settings(text.split())
        with ProcessPoolExecutor(args.jobs) as pool:
            results = list(pool.map(run_object, OBJECTS, [params] * len(OBJECTS),
                                    [args.clutter] * len(OBJECTS), [args.seed] * len(OBJECTS)))
        records += [json.dumps({"setting": text} | r) for res in results for r in res["records"]]
        block = f"[{text or 'defaults'}]\n  {report(results)}"
        print(block, end="", flush=True)
        out.write(block)
    wall = f"wall {time.perf_counter() - t0:.0f} s with {args.jobs} processes\n"
    print(wall, end="")
    out.write(wall)
    if args.records:
        atomic_write_text(args.records, "".join(line + "\n" for line in records))
    if args.markdown:
        write_markdown(args.markdown, __file__, None, out.getvalue())
    return 0


if __name__ == "__main__":
    sys.exit(main())
