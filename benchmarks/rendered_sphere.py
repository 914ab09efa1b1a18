"""The whole viewing sphere, rendered: rotation and translation errors in the camera frame.

A mesh of ``pybullet_data`` (r2d2 by default) is rendered with pybullet's
CPU renderer, framed (the camera looks at the centre of its bounding box
from where the box's sphere fits the view). Training views: azimuths every
20 degrees at elevations -30, -15, ..., 60 degrees (126 views), on black,
with their masks. Test views: random azimuths and elevations in
[-30, 60] degrees, pasted on clutter at a random position, scale 0.8-1.25
and in-plane angle within +-30 degrees with 20% of the object hidden
(:func:`posevote.evaluation.synthetic.paste_on_clutter`).

The object's height in metres is learnt from the training distances
(:func:`posevote.camera.object_height_from_distances`). A test image is
read with the renderer's focal length and the canvas centre as the camera;
the true pose is the rendered viewpoint with the pasted in-plane angle, and
the true translation the pasted position's ray at the rendered distance
divided by the pasted scale. Reported: the geodesic rotation error, the
translation error as a share of the true depth, the detection rate (box
IoU >= 0.5) and the seconds per image.

``--clean`` tests the views as rendered, on black, with the ``default``
preset: the sphere model without clutter, scale or in-plane search.

Usage::

    python benchmarks/rendered_sphere.py [--mesh r2d2.urdf] [--images 40] [--clean] [--jobs 2]
        [--param NAME=VALUE ...] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

from _markdown import write_markdown  # noqa: E402
from _settings import parse_settings  # noqa: E402

from posevote import Camera, PoseEstimator  # noqa: E402
from posevote.camera import object_height_from_distances  # noqa: E402
from posevote.demo import render_focal, render_turntable  # noqa: E402
from posevote.evaluation.metrics import box_iou  # noqa: E402
from posevote.evaluation.synthetic import PastedView, paste_on_clutter  # noqa: E402
from posevote.geometry import box_centre, rotation_from_pose  # noqa: E402

ELEVATIONS_DEG = (-30, -15, 0, 15, 30, 45, 60)
AZIMUTH_STEP_DEG = 20
SIZE = 128
CANVAS = (256, 256)
MESHES = {"r2d2.urdf": (0.0, 0.0, 0.0), "duck_vhacd.urdf": (np.pi / 2, 0.0, 0.0)}


def training_views(mesh: str, elevations: tuple[float, ...]) -> tuple[list, np.ndarray]:
    views, poses = [], []
    for el in elevations:
        az = np.radians(np.arange(0, 360, AZIMUTH_STEP_DEG))
        for v in render_turntable(az, size=SIZE, elevation_deg=el, distance=None, mesh=mesh,
                                  base_euler=MESHES[mesh]):
            views.append(v)
            poses.append([v.azimuth, np.radians(el), 0.0])
    return views, np.array(poses)


def geodesic_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(a @ b.T) - 1.0) / 2.0, -1.0, 1.0))))


def run_chunk(mesh: str, params: dict, seeds: list[int], clean: bool = False,
              elevations: tuple[float, ...] = ELEVATIONS_DEG) -> list[dict]:
    views, poses = training_views(mesh, elevations)
    focal = render_focal(SIZE)
    height = object_height_from_distances([v.box[3] for v in views], [v.distance for v in views],
                                          Camera(fx=focal, fy=focal, cx=0.0, cy=0.0))
    est = PoseEstimator.from_preset("default" if clean else "cluttered",
                                    **{"min_score": 0.0, **params}).fit(
        [v.image for v in views], poses, boxes=[v.box for v in views],
        masks=[v.mask for v in views], object_height_m=height)
    shape = (SIZE, SIZE) if clean else CANVAS
    camera = Camera(fx=focal, fy=focal, cx=(shape[1] - 1) / 2.0, cy=(shape[0] - 1) / 2.0)
    out = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        az = float(rng.uniform(0.0, 2 * np.pi))
        el = float(rng.uniform(min(elevations), max(elevations)))
        view = render_turntable(np.array([az]), size=SIZE, elevation_deg=el, distance=None,
                                mesh=mesh, base_euler=MESHES[mesh])[0]
        pasted = paste_on_clutter(view.image, view.box, rng=rng, canvas_shape=CANVAS,
                                  scale_range=(0.8, 1.25), mask=view.mask) if not clean else \
            PastedView(image=view.image, position=box_centre(view.box), scale=1.0, inplane=0.0,
                       box=tuple(view.box), occluded_fraction=0.0)
        t0 = time.perf_counter()
        result = est.estimate(pasted.image, camera=camera)
        seconds = time.perf_counter() - t0
        truth_R = rotation_from_pose(az, np.radians(el), pasted.inplane)
        depth = view.distance / pasted.scale
        u, v = pasted.position
        truth_t = np.array([(u - camera.cx) / focal * depth, (v - camera.cy) / focal * depth,
                            depth])
        rec = {"seed": seed, "azimuth_deg": np.degrees(az), "elevation_deg": el,
               "seconds": seconds, "rotation_deg": 180.0, "translation_pct": np.inf,
               "detected": False}
        b = result.best
        if b is not None:
            rec["rotation_deg"] = geodesic_deg(np.array(b.R_cam_obj), truth_R)
            rec["translation_pct"] = float(100 * np.linalg.norm(np.array(b.t_cam_obj) - truth_t)
                                           / depth)
            rec["detected"] = bool(box_iou(b.box, pasted.box) >= 0.5)
        out.append(rec)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mesh", default="r2d2.urdf", choices=sorted(MESHES))
    ap.add_argument("--images", type=int, default=40)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--elevations", default=",".join(map(str, ELEVATIONS_DEG)),
                    help="training elevations, degrees (tests drawn between the extremes)")
    ap.add_argument("--clean", action="store_true",
                    help="test views as rendered, on black (the default preset): the sphere "
                         "model without clutter")
    ap.add_argument("--param", action="append", default=[], help="NAME=VALUE estimator setting")
    ap.add_argument("--markdown", help="also write the printed report here")
    args = ap.parse_args(argv)
    params = parse_settings(args.param)
    elevations = tuple(float(e) for e in args.elevations.split(","))
    seeds = [args.seed * 100_000 + i for i in range(args.images)]
    chunks = [seeds[i::args.jobs] for i in range(args.jobs)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        records = sorted((r for part in pool.map(run_chunk, [args.mesh] * len(chunks),
                                                 [params] * len(chunks), chunks,
                                                 [args.clean] * len(chunks),
                                                 [elevations] * len(chunks)) for r in part),
                         key=lambda r: r["seed"])
    wall = time.perf_counter() - t0
    report = io.StringIO()
    with contextlib.redirect_stdout(report):
        rot = np.array([r["rotation_deg"] for r in records])
        tra = np.array([r["translation_pct"] for r in records])
        print(f"rendered sphere, {args.mesh}: {len(elevations) * 360 // AZIMUTH_STEP_DEG} "
              f"training views (azimuth every {AZIMUTH_STEP_DEG} deg, elevations "
              f"{elevations}), {len(records)} test images "
              f"{'as rendered, on black' if args.clean else 'pasted on clutter'}; preset "
              f"{'default' if args.clean else 'cluttered'}, overrides {params or 'none'}")
        print(f"rotation error: median {np.median(rot):.2f} deg, mean {np.mean(rot):.2f} deg, "
              f"{100 * np.mean(rot < 10):.1f}% under 10 deg, {100 * np.mean(rot < 30):.1f}% under "
              f"30 deg")
        print(f"translation error: median {np.median(tra):.2f}% of the depth; detected "
              f"{100 * np.mean([r['detected'] for r in records]):.1f}%")
        print(f"seconds per image: median {np.median([r['seconds'] for r in records]):.2f}; wall "
              f"{wall:.0f} s with {args.jobs} processes")
    print(report.getvalue(), end="")
    if args.markdown:
        write_markdown(args.markdown, __file__, argv, report.getvalue())
    return 0


if __name__ == "__main__":
    sys.exit(main())
