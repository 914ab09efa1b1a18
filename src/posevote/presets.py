"""Named presets: the configurations tuned on real data, each with where it was chosen.

A preset is a set of :class:`~posevote.estimator.PoseEstimator` parameters
and its provenance: the data it was chosen on, the script that chose it and
what it measured there (``docs/DEFAULTS.md`` has every value's row).
``PoseEstimator.from_preset(name, **overrides)`` builds one; the evaluation
protocols and the demo build theirs from presets only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from posevote._options import params_to_json
from posevote.appearance import AppearanceOptions
from posevote.features.edges import EdgeOptions
from posevote.inference.setup import SearchOptions
from posevote.model.kernels import KernelOptions
from posevote.recognition import RecognitionOptions
from posevote.refinement import RefineOptions
from posevote.templates import TemplateOptions


@dataclass(frozen=True, kw_only=True)
class Preset:
    """A named configuration and its provenance.

    Attributes
    ----------
    name : str
    description : str
        One line: what it is for.
    chosen_on : str
        The data its values were chosen on (training data only).
    script : str
        The script that measured the choice.
    measured : str
        What it measured, and where the result file is.
    params : dict
        :class:`~posevote.estimator.PoseEstimator` parameters (the others at
        their defaults).
    """

    name: str
    description: str
    chosen_on: str
    script: str
    measured: str
    params: dict[str, Any] = field(default_factory=dict)


# The EPFL search: a regular 10-degree viewpoint grid with a 5-degree pose
# kernel (a car sequence has a view every 3 degrees), scales 0.7-1.45 (the
# spread of the cars' box heights around the pooled reference), 150 features
# per view, the kernel in object units with the chance correction, and the
# most similar training car's model re-estimating near the category's mode.
_EPFL_SEARCH = SearchOptions(viewpoint_step_deg=10.0, scale_range=(0.7, 1.45), scale_steps=6,
                             object_kernel=True, chance_correction=True, density_cap=0.6,
                             max_search_features=1000, calibration=(0.503, 4.009, 7.664))

# Each preset's ``SearchOptions.calibration``: the logistic fit of "right" (within 30 deg,
# box found) on its development estimates, wrong objects and empty frames among them: those
# it reports (over its min_score), or every one where that calibrates them better held out
# (benchmarks/calibrate_probability.py, docs/results/probability_calibration.md).

PRESETS: dict[str, Preset] = {p.name: p for p in (
    Preset(
        name="default",
        description="clean views of one object at a fixed distance, upright (COIL-100)",
        chosen_on="COIL-100, the 16 objects of the paper: views at 0, 40, ..., 320 deg "
                  "trained, the training views between them tested",
        script="benchmarks/tune_coil_cv.py",
        measured="COIL instance protocol 0.69 / 1.33 deg median / mean with the keypoint "
                 "step, chosen on the 40 development objects (docs/results/coil_instance.md, "
                 "docs/DEFAULTS.md); min_score by 5-fold cross-validation "
                 "over the 40 development objects: 91% of right-object views kept, 85% of "
                 "other objects' views and background crops rejected "
                 "(benchmarks/rejection_threshold.py, docs/results/rejection_threshold.md)",
        # The threshold of the best balanced accuracy between views of the object
        # and views of the 39 other objects plus background crops.
        params={"min_score": 0.54,
                "search": SearchOptions(calibration=(0.918, 2.056, 2.760)),
                "refine": RefineOptions(keypoints=True)}),
    Preset(
        name="cluttered",
        description="one object anywhere in clutter, tilted by up to 30 deg, 0.4-2.6 times "
                    "the training size (the views shrunk for the smaller, the image halved "
                    "for the larger), partly occluded",
        chosen_on="COIL-100 training views pasted on clutter (self-test and cross-validation "
                  "on the training views)",
        script="benchmarks/coil_instance.py --selftest --clutter / --cv --clutter",
        measured="COIL instance protocol in clutter 3.64 / 6.81 deg, 79.2% of positions "
                 "within 5 px (docs/results/coil_instance_clutter.md); the template "
                 "re-ranking chosen on the development clutter CVs (docs/DEFAULTS.md); "
                 "min_score (on the contrast) and the image levels by 5-fold "
                 "cross-validation over the 40 development objects on the frames benchmark "
                 "(benchmarks/default_thresholds.py, docs/results/default_thresholds.md)",
        # The lowest contrast that at most 2.5% of the empty frames exceed.
        params={"min_score": 5.351,
                "search": SearchOptions(inplane_range_deg=(-30.0, 30.0), inplane_step_deg=5.0,
                                        scale_range=(0.7, 1.3), scale_steps=7,
                                        object_kernel=True, chance_correction=True,
                                        density_cap=0.5, calibration=(0.346, 0.830, -0.539),
                                        image_levels=(1.8, 1.0, 0.5), contrast=True),
                "refine": RefineOptions(rescale=False, local="profile", share_scale=True,
                                        keypoints=True),
                "templates": TemplateOptions()}),
    Preset(
        name="turntable",
        description="dense turntable views of one object, full frames at a fixed distance, "
                    "features morphed between neighbouring views (EPFL single car)",
        chosen_on="EPFL cars 2-10, the epfl-single protocol on each (car 1 only reports)",
        script="benchmarks/tune_epfl.py --protocol epfl-single",
        measured="epfl-single (car 1, 40 training frames) 0.58 / 0.90 deg "
                 "(docs/results/epfl-single); min_score as cluttered's "
                 "(docs/results/default_thresholds.md)",
        params={"min_score": 0.138, "edges": EdgeOptions(max_train_features=150),
                "search": SearchOptions(viewpoint_subdivisions=2, scale_steps=5,
                                        object_kernel=True, chance_correction=True,
                                        calibration=(0.0, 9.026, 15.224)),
                "refine": RefineOptions(rescale=False, local="profile"), "morph_views": True}),
    Preset(
        name="category",
        description="a category learnt from several instances, found in full cluttered "
                    "frames, with HOG verification and the nearest view (EPFL 10/10)",
        chosen_on="EPFL cars 1-10, the two-fold epfl-cv (cars 1-5 <-> 6-10); the search "
                  "re-checked on the five-fold epfl-cv (8 training cars per fold)",
        script="benchmarks/tune_epfl.py",
        measured="five-fold epfl-cv every 4th frame 3.98 / 22.7 deg, 86.9% under 45 deg, "
                 "8.1% flips, 97.3% found (docs/results/epfl-cv); min_score by the "
                 "epfl-cv folds and empty mosaics of photographs "
                 "(benchmarks/default_thresholds.py, docs/results/default_thresholds.md)",
        params={"min_score": 0.109, "edges": EdgeOptions(max_train_features=150),
                "kernel": KernelOptions(position_sigma=6.0, viewpoint_bandwidth_deg=5.0),
                "search": _EPFL_SEARCH,
                # The appearance step regresses the box and reads the viewpoint itself.
                "refine": RefineOptions(rescale=False, outline=False),
                "recognition": RecognitionOptions(margin=1.0, search=False),
                "appearance": AppearanceOptions()}),
)}


def get_preset(name: str) -> Preset:
    """The preset called ``name``.

    Raises
    ------
    ValueError
        On an unknown name (the message lists the presets).
    """
    if not isinstance(name, str) or name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")
    return PRESETS[name]


def nearest_preset(params: dict[str, Any], defaults: dict[str, Any]) -> dict[str, Any]:
    """The preset that ``params`` differ least from, and what differs (JSON-ready).

    Parameters
    ----------
    params : dict
        An estimator's parameters (``get_params(deep=False)``).
    defaults : dict
        The estimator's defaults, which a preset's parameters are laid over.

    Returns
    -------
    dict
        ``{"name": ..., "overrides": {...}}``, as recorded in a model file's header.
    """
    best: tuple[int, str, dict[str, Any]] | None = None
    for name, preset in PRESETS.items():
        theirs = {**defaults, **preset.params}
        diff = {k: v for k, v in params.items() if theirs.get(k) != v}
        if best is None or len(diff) < best[0]:
            best = (len(diff), name, diff)
    if best is None:
        raise ValueError("no presets defined")
    return {"name": best[1], "overrides": params_to_json(best[2])}
