"""The rendered-sphere protocol: the whole viewing sphere, scored in the camera frame.

A mesh of ``pybullet_data`` (r2d2 by default) is rendered with pybullet's CPU
renderer, framed so that its bounding sphere fits the view (with an image of
``pybullet_data`` laid over it, where the setup names one). Training: azimuths
every :data:`AZIMUTH_STEP_DEG` at the elevations :data:`ELEVATIONS_DEG`
(468 views; the setup may name others), on black, with their masks and the image and depth of the
mesh's origin (``fit(..., origins=)``, so that ``t_cam_obj`` names the mesh
origin, as a robot needs, not the box centre), their features morphed
toward the neighbouring views in azimuth and elevation for the tests in
clutter (``morph_views``, :mod:`posevote.model.morph`); the object's height in
metres is learnt from the training distances
(:func:`posevote.camera.object_height_from_distances`). Test: views at
random azimuths and elevations between the extreme training elevations, so
almost never a training view, pasted on clutter at a random position, scale
(:data:`SCALE_RANGE`) and in-plane angle within 30 degrees with 20% of the
object hidden (:func:`posevote.evaluation.synthetic.paste_on_clutter`),
estimated with the ``cluttered`` preset and the renderer's camera. With
``clean`` the test views are tested as rendered, on black, with the
``default`` preset.

The true rotation is the rendered viewpoint with the pasted in-plane angle;
the true translation is the mesh origin's: its rendered image moved as the
view was pasted (turned and scaled about the box centre), on the ray at its
rendered depth divided by the pasted scale. Reported: the geodesic rotation error (median,
mean, share under 10 and 30 degrees, flip rate: over 135 degrees), the elevation error's
median, the translation error as a share of
the true depth, the detection rate (box IoU >= 0.5) and the seconds per
image, in ``report.md`` and ``summary.json``, one record per test image in
``records.jsonl``, and the rotation errors plotted against the test
elevation in ``rotation_errors.png``. Everything is rendered on the fly:
nothing to download.
"""

from __future__ import annotations

import contextlib
import io
import json
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from posevote._io import atomic_write_text
from posevote._parallel import ordered_map
from posevote.batch import run_image
from posevote.camera import (
    Camera,
    object_height_from_distances,
    origin_depth_factors,
    scale_range_for_depths,
)
from posevote.estimator import PoseEstimator
from posevote.evaluation.metrics import FLIP_DEG, summarize_errors
from posevote.evaluation.rendering import (
    MESHES,
    RenderedView,
    render_focal,
    render_turntable,
    texture_path,
)
from posevote.evaluation.report import row_steps
from posevote.evaluation.synthetic import PastedView, paste_on_clutter
from posevote.geometry import (
    box_centre,
    box_iou,
    rotate_points,
    rotation_angle,
    rotation_from_pose,
)

#: Training elevations, degrees, and the azimuths' step: chosen on the development seeds
#: 1-4 among coarser grids (docs/DEFAULTS.md).
ELEVATIONS_DEG = (-30.0, -22.5, -15.0, -7.5, 0.0, 7.5, 15.0, 22.5, 30.0, 37.5, 45.0, 52.5,
                  60.0)
AZIMUTH_STEP_DEG = 10
#: Side of the rendered views and size of the cluttered canvas, pixels.
SIZE = 128
CANVAS = (256, 256)
#: Scales at which test views are pasted.
SCALE_RANGE = (0.8, 1.25)
#: The most test images one run may hold.
MAX_IMAGES = 10_000


@dataclass(frozen=True, kw_only=True)
class SphereSetup:
    """What one run of the protocol renders, trains and tests.

    Attributes
    ----------
    mesh : str
        A key of :data:`MESHES`.
    n_images : int
        Test images.
    seed : int
        Test image ``i`` is drawn with seed ``seed * 100000 + i``.
    elevations_deg : tuple of float
        Training elevations; test elevations are drawn between the extremes.
    clean : bool
        Test the views as rendered, on black, with the ``default`` preset.
    params : mapping
        Estimator settings over the preset (``set_params`` keys).
    known_depths : bool
        Tell the estimator the depths the test views are pasted at (the
        render distance over :data:`SCALE_RANGE`), in metres through the
        camera (:func:`posevote.camera.scale_range_for_depths`), as a robot
        that knows its working distances would.
    texture : str or None
        An image of ``pybullet_data`` laid over the mesh by its texture coordinates
        (:func:`posevote.evaluation.rendering.render_turntable`); None keeps its material.
    azimuth_step_deg : float
        Training azimuths are this many degrees apart, at every elevation.
    """

    mesh: str = "r2d2.urdf"
    n_images: int = 40
    seed: int = 0
    elevations_deg: tuple[float, ...] = ELEVATIONS_DEG
    clean: bool = False
    params: Mapping[str, Any] = field(default_factory=dict)
    known_depths: bool = False
    texture: str | None = None
    azimuth_step_deg: float = AZIMUTH_STEP_DEG

    def __post_init__(self) -> None:
        if self.mesh not in MESHES:
            raise ValueError(f"mesh must be one of {sorted(MESHES)}, got {self.mesh!r}")
        if not (isinstance(self.n_images, int) and 1 <= self.n_images <= MAX_IMAGES):
            raise ValueError(f"n_images must be an integer in [1, {MAX_IMAGES}], "
                             f"got {self.n_images!r}")
        if not (isinstance(self.seed, int) and 0 <= self.seed < 2**31 // 100_000):
            raise ValueError(f"seed must be an integer in [0, {2**31 // 100_000}), "
                             f"got {self.seed!r}")
        els = self.elevations_deg
        if not (len(els) >= 1 and all(np.isfinite(e) and -80 <= e <= 80 for e in els)):
            raise ValueError(f"elevations_deg must be degrees in [-80, 80], got {els!r}")
        step = self.azimuth_step_deg
        if not (isinstance(step, (int, float)) and 1 <= step <= 180 and (360 / step).is_integer()):
            raise ValueError(f"azimuth_step_deg must divide 360 degrees, from 1 to 180, "
                             f"got {step!r}")
        if self.texture is not None:
            try:
                texture_path(self.texture)
            except FileNotFoundError as exc:
                raise ValueError(str(exc)) from None

    @property
    def name(self) -> str:
        """The rendered object: its mesh, and its texture where one is laid over it."""
        return self.mesh if self.texture is None else f"{self.mesh} + {self.texture}"

    @property
    def preset(self) -> str:
        """The preset the model starts from."""
        return "default" if self.clean else "cluttered"

    @property
    def morphed(self) -> bool:
        """Whether the training views' features are morphed toward their neighbours: in
        clutter, where it was chosen on the development seeds 1-8; on black it lost
        (docs/DEFAULTS.md)."""
        return not self.clean

    def seeds(self) -> list[int]:
        """The seed of every test image."""
        return [self.seed * 100_000 + i for i in range(self.n_images)]


def _render(azimuths: NDArray[np.float64], elevation_deg: float, setup: SphereSetup
            ) -> list[RenderedView]:
    # pybullet prints its build time on stdout when it connects.
    with contextlib.redirect_stdout(io.StringIO()):
        return render_turntable(azimuths, size=SIZE, elevation_deg=elevation_deg, distance=None,
                                mesh=setup.mesh, base_euler=MESHES[setup.mesh],
                                texture=setup.texture)


def train(setup: SphereSetup) -> PoseEstimator:
    """Render the training views and fit the model (with the object's height in metres and
    the mesh origin's image and depth factor in each view)."""
    views, poses = [], []
    for el in setup.elevations_deg:
        for v in _render(np.radians(np.arange(0.0, 360.0, setup.azimuth_step_deg)), el, setup):
            views.append(v)
            poses.append([v.azimuth, np.radians(el), 0.0])
    camera = render_camera()
    heights = [v.box[3] for v in views]
    height = object_height_from_distances(heights, [v.distance for v in views], camera)
    factors = origin_depth_factors([v.origin[2] for v in views], camera, object_height_m=height,
                                   reference_size_px=float(np.median(heights)))
    origins = np.column_stack([[camera.project(v.origin) for v in views], factors])
    # Morphed between the grid's neighbours, the model between views moves as the object does.
    est = PoseEstimator.from_preset(setup.preset, **{"min_score": 0.0,
                                                     "morph_views": setup.morphed,
                                                     **setup.params})
    return est.fit([v.image for v in views], np.array(poses), boxes=[v.box for v in views],
                   masks=[v.mask for v in views], object_height_m=height, origins=origins)


def render_camera() -> Camera:
    """The renderer's camera for a rendered view (pixel centres at integers)."""
    focal = render_focal(SIZE)
    return Camera(fx=focal, fy=focal, cx=(SIZE - 1) / 2.0, cy=(SIZE - 1) / 2.0)


def true_translation(view: RenderedView, pasted: PastedView, camera: Camera
                     ) -> NDArray[np.float64]:
    """The mesh origin in the test camera's frame, metres: its image in the render moved as
    the view was pasted (turned and scaled about the box centre), at its depth over the
    pasted scale."""
    offset = render_camera().project(view.origin) - np.asarray(box_centre(view.box))
    u, v = np.asarray(pasted.position) + pasted.scale * rotate_points(offset, pasted.inplane)
    return camera.ray_point(float(u), float(v), float(view.origin[2]) / pasted.scale)


def estimate_record(est: PoseEstimator, item: tuple[SphereSetup, int]) -> dict[str, Any]:
    """Render test image ``seed`` of ``item = (setup, seed)``, estimate it and score it (in a
    worker process, through :func:`posevote.batch.run_image`)."""
    setup, seed = item
    rng = np.random.default_rng(seed)
    els = setup.elevations_deg
    az = float(rng.uniform(0.0, 2 * np.pi))
    el = float(rng.uniform(min(els), max(els)))
    view = _render(np.array([az]), el, setup)[0]
    if setup.clean:
        pasted = PastedView(image=view.image, position=box_centre(view.box), scale=1.0,
                            inplane=0.0, box=tuple(view.box), occluded_fraction=0.0)
        shape: tuple[int, int] = (SIZE, SIZE)
    else:
        pasted = paste_on_clutter(view.image, view.box, rng=rng, canvas_shape=CANVAS,
                                  scale_range=SCALE_RANGE, mask=view.mask)
        shape = CANVAS
    # The renderer's lens over the canvas: its centre moves, its focal length does not.
    camera = replace(render_camera(), cx=(shape[1] - 1) / 2.0, cy=(shape[0] - 1) / 2.0)
    if setup.known_depths:
        depths = (view.distance / SCALE_RANGE[1], view.distance / SCALE_RANGE[0])
        est.set_params(search__scale_range=scale_range_for_depths(
            depths, camera, object_height_m=est.object_height_m_,
            reference_size_px=est.model_.reference_size))
    start = time.perf_counter()
    result = est.estimate(pasted.image, camera=camera)
    seconds = time.perf_counter() - start
    truth_t = true_translation(view, pasted, camera)
    depth = float(truth_t[2])
    rec: dict[str, Any] = {"seed": seed, "azimuth_deg": float(np.degrees(az)), "elevation_deg": el,
                           "inplane_deg": float(np.degrees(pasted.inplane)),
                           "scale": float(pasted.scale), "depth_m": float(depth),
                           "seconds": seconds, "found": result.found, "rotation_deg": 180.0,
                           "elevation_error_deg": None, "translation_pct": None,
                           "detected": False}
    best = result.best
    if best is not None and best.R_cam_obj is not None and best.t_cam_obj is not None:
        rec["rotation_deg"] = float(np.degrees(rotation_angle(
            best.R_cam_obj, rotation_from_pose(az, np.radians(el), pasted.inplane))))
        rec["elevation_error_deg"] = abs(best.elevation_deg - el)
        rec["translation_pct"] = float(100 * np.linalg.norm(np.array(best.t_cam_obj) - truth_t)
                                       / depth)
        rec["detected"] = bool(box_iou(best.box, pasted.box) >= 0.5)
    return rec


def summarize(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The protocol's figures over the records (a missed image counts 180 degrees, no translation).

    A flip is a rotation error over ``FLIP_DEG`` (the object taken for its half-turned self).
    """
    rot = np.array([r["rotation_deg"] for r in records], dtype=float)
    # A missed image's elevation counts as the widest error the training rings allow.
    ele = np.array([90.0 if r.get("elevation_error_deg") is None else r["elevation_error_deg"]
                    for r in records], dtype=float)
    tra = np.array([np.inf if r["translation_pct"] is None else r["translation_pct"]
                    for r in records])
    errors = summarize_errors(rot)
    return {"n": len(records),
            "rotation_median_deg": errors["median"], "rotation_mean_deg": errors["mean"],
            "rotation_under_10_pct": float(100 * np.mean(rot < 10)),
            "rotation_under_30_pct": float(100 * np.mean(rot < 30)),
            "flip_rate_pct": errors["flip_rate"],
            "elevation_median_deg": float(np.median(ele)),
            "translation_median_pct": float(np.median(tra)),
            "translation_under_2_pct": float(100 * np.mean(tra < 2)),
            "detected_pct": float(100 * np.mean([r["detected"] for r in records])),
            "seconds_median": float(np.median([r["seconds"] for r in records]))}


def report_text(setup: SphereSetup, summary: dict[str, Any], n_views: int) -> str:
    """The report in words (markdown)."""
    where = "as rendered, on black" if setup.clean else \
        "pasted on 256 x 256 clutter, scale 0.8-1.25, in-plane within 30 deg, 20% hidden"
    told = "; the test depths known (the scales searched from them)" \
        if setup.known_depths else ""
    return (f"# rendered-sphere: {setup.name}\n\n"
            f"{n_views} training views (azimuth every {setup.azimuth_step_deg:g} deg at elevations "
            f"{', '.join(f'{e:g}' for e in setup.elevations_deg)} deg); {summary['n']} test views "
            f"at random azimuths and elevations, {where}; preset `{setup.preset}`"
            f"{' with the features morphed between neighbouring views' if setup.morphed else ''}"
            ", overrides "
            f"{dict(setup.params) or 'none'}{told}; seed {setup.seed}. The translation error is "
            "`t_cam_obj`'s distance from the mesh origin (learnt in each training view).\n\n"
            f"Steps: {row_steps(setup.preset, dict(setup.params))}.\n\n"
            f"| rotation median ° | rotation mean ° | % < 10° | % < 30° | flips % (> {FLIP_DEG:g}°) "
            "| elevation median ° "
            "| translation median (% of depth) | % translation < 2% | detected % | s / image |\n"
            "|---|---|---|---|---|---|---|---|---|---|\n"
            f"| {summary['rotation_median_deg']:.2f} | {summary['rotation_mean_deg']:.2f} | "
            f"{summary['rotation_under_10_pct']:.1f} | {summary['rotation_under_30_pct']:.1f} | "
            f"{summary['flip_rate_pct']:.1f} | {summary['elevation_median_deg']:.2f} | "
            f"{summary['translation_median_pct']:.2f} | {summary['translation_under_2_pct']:.1f} | "
            f"{summary['detected_pct']:.1f} | {summary['seconds_median']:.2f} |\n")


def plot_rotation_errors(records: Sequence[dict[str, Any]], path: Path, *, title: str = "") -> None:
    """Rotation error against the test elevation, and its cumulative share."""
    from posevote.evaluation.report import _figure, _save

    plt = _figure()
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 3.6))
    rot = np.array([r["rotation_deg"] for r in records], dtype=float)
    el = np.array([r["elevation_deg"] for r in records], dtype=float)
    det = np.array([r["detected"] for r in records], dtype=bool)
    left.scatter(el[det], rot[det], s=14, label="detected")
    left.scatter(el[~det], rot[~det], s=14, marker="x", label="not detected")
    left.axhline(FLIP_DEG, color="grey", lw=0.8, ls="--", label=f"flip (> {FLIP_DEG:g} deg)")
    left.set(xlabel="test elevation (deg)", ylabel="rotation error (deg)", ylim=(0, 185))
    left.legend(fontsize=8)
    xs = np.sort(rot)
    right.plot(xs, 100 * np.arange(1, len(xs) + 1) / len(xs))
    for x in (10, 30):
        right.axvline(x, color="grey", lw=0.8, ls=":")
    right.axvline(FLIP_DEG, color="grey", lw=0.8, ls="--")
    right.set(xlabel="rotation error (deg)", ylabel="% of test images within", xlim=(0, 180),
              ylim=(0, 100))
    fig.suptitle(title)
    _save(fig, path)
    plt.close(fig)


def run_sphere(setup: SphereSetup, out: str | Path, *, jobs: int = 1, scheduler: Any = None,
               progress: Callable[[int, int], None] | None = None,
               log: Callable[[str], None] = lambda _m: None) -> dict[str, Any]:
    """Train, test and write the report of the protocol in ``out`` (see the module docstring).

    Parameters
    ----------
    setup : SphereSetup
    out : path
        Results folder (created): ``model.npz``, ``records.jsonl``, ``summary.json``,
        ``report.md``, ``rotation_errors.png``.
    jobs : int, optional
        Worker processes for the test images.
    scheduler : str or distributed.Client, optional
        Estimate on this Dask cluster instead.
    progress : callable, optional
        Called with (done, total) after each test image.
    log : callable, optional
        Called with a line of text at each stage.

    Returns
    -------
    dict
        The summary (:func:`summarize`) with the wall time and the setup.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    log(f"rendering and training {setup.name} ({len(setup.elevations_deg)} elevations)")
    est = train(setup)
    n_views = len(est.model_.view_azimuth)
    model_path = out / "model.npz"
    est.save(model_path)
    seeds = setup.seeds()
    records = []
    if progress is not None:
        progress(0, len(seeds))
    for rec in ordered_map(run_image, [(estimate_record, str(model_path), {}, (setup, s))
                                       for s in seeds],
                           jobs=jobs, scheduler=scheduler):
        records.append(rec)
        if progress is not None:
            progress(len(records), len(seeds))
    summary = summarize(records)
    summary.update(wall_seconds=time.perf_counter() - start, jobs=jobs, mesh=setup.mesh,
                   texture=setup.texture, azimuth_step_deg=setup.azimuth_step_deg,
                   n_training_views=n_views, elevations_deg=list(setup.elevations_deg),
                   clean=setup.clean, seed=setup.seed, params=dict(setup.params))
    atomic_write_text(out / "records.jsonl", "".join(json.dumps(r) + "\n" for r in records))
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2, default=str) + "\n")
    atomic_write_text(out / "report.md", report_text(setup, summary, n_views))
    plot_rotation_errors(records, out / "rotation_errors.png",
                         title=f"rendered sphere, {setup.name}, {setup.preset} preset")
    return summary
