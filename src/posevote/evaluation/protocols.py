"""The paper's evaluation protocols (METHOD.md), as data.

A :class:`Protocol` is a list of train/test :class:`Split` s, the preset
its estimators start from (:mod:`posevote.presets`) and the ablation
:class:`Row` s to run on each split (overrides of that preset). The runner
(:mod:`posevote.evaluation.runner`) trains, estimates, scores and reports.
Every protocol has the paper's own configuration as rows of their own, beside
the preset's row, and a row's name says everything it runs. How each
preset value was chosen is in ``docs/DEFAULTS.md``; cars 11-20 and the COIL
objects outside ``../shared/data`` were never used to choose anything.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from posevote.data.training_set import TrainingSet, read_coil, read_epfl
from posevote.recognition import RecognitionOptions
from posevote.refinement import RefineOptions

#: The COIL-100 categories of Fig. 5: (seen instances, unseen instances, half-turn symmetric).
COIL_CATEGORIES: dict[str, tuple[tuple[int, ...], tuple[int, ...], bool]] = {
    "cars": ((6, 8, 23, 76), (15, 91), False),
    "boxes": ((1, 31, 54, 79), (46, 96), True),
    "bottles": ((13, 64), (22, 33), True),
}

@dataclass(frozen=True, kw_only=True)
class Split:
    """One train/test split.

    Attributes
    ----------
    name : str
        Identifier (file-name safe).
    train : TrainingSet
        What the model is trained on.
    test : TrainingSet
        The test images with their true poses and boxes.
    groups : tuple of str
        Group of every test image (``seen`` / ``unseen``, or the category),
        for the per-group tables.
    half_turn : bool
        Errors are taken on the half circle (mod 180 degrees).
    """

    name: str
    train: TrainingSet
    test: TrainingSet
    groups: tuple[str, ...]
    half_turn: bool = False


@dataclass(frozen=True, kw_only=True)
class Row:
    """One ablation row: overrides of the protocol's preset.

    Attributes
    ----------
    name : str
        Row label, as in the paper's tables.
    params : dict or None
        :meth:`~posevote.estimator.PoseEstimator.set_params` overrides of the
        protocol's preset; None marks a row that cannot be run (the
        reason is in ``note``), never faked.
    note : str
        Why the row is not available, or what it means.
    """

    name: str
    params: dict[str, Any] | None
    note: str = ""


@dataclass(frozen=True, kw_only=True)
class Protocol:
    """A named evaluation protocol.

    Attributes
    ----------
    name : str
        One of :data:`PROTOCOLS`.
    description : str
        One paragraph, for the report.
    splits : tuple of Split
    rows : tuple of Row
    preset : str
        The preset every row starts from (:mod:`posevote.presets`).
    published : str
        Markdown table of the published numbers to compare with.
    main_row : str
        The row the plots show (default: the first).
    default_rows : tuple of str
        The rows a run without an explicit row list runs (empty: all).
    """

    name: str
    description: str
    splits: tuple[Split, ...]
    rows: tuple[Row, ...]
    preset: str = "default"
    published: str = ""
    main_row: str = ""
    default_rows: tuple[str, ...] = ()


PROTOCOLS = ("coil-category", "coil-loio", "epfl-single", "epfl-10-10", "epfl-cv")

_NO_RECOGNITION = {"recognition": None}
# The paper's rows without fitting: the modes are the best probes.
_NO_FIT = {"refine": RefineOptions(fit=False, rescale=False)}

_ABLATION = (
    Row(name="no weights", params={"weights": False, **_NO_FIT, **_NO_RECOGNITION}),
    Row(name="weights", params={**_NO_FIT, **_NO_RECOGNITION}),
    Row(name="weights + pruning", params={"prune": "moderate", **_NO_FIT, **_NO_RECOGNITION}),
    Row(name="weights + pruning + fitting", params={"prune": "moderate", **_NO_RECOGNITION}),
    Row(name="refined with instance model (paper: near the category's mode)",
        params={"prune": "moderate", "recognition": RecognitionOptions(search=False)},
        note="the paper's Sec. III-B: instances scored at the category's modes, the winner "
             "re-estimates near its mode"),
    Row(name="refined with instance model + instance search",
        params={"prune": "moderate"},
        note="beyond the paper: every instance's model estimates the pose over all viewpoints "
             "and is judged at its own estimate (RecognitionOptions.search)"),
    Row(name="refined with instance model + instance search + morphing",
        params={"prune": "moderate", "morph_views": True, "search__viewpoint_subdivisions": 2},
        note="beyond the paper: features morphed between training views, two probes per gap"),
)

_APPEARANCE = "HOG verification of 40 candidates, box regression, nearest-view viewpoint"
_EPFL_ROWS = (
    Row(name="paper: weights + fitting",
        params={"appearance": None, "recognition": None, "search__rerank": "coverage",
                "search__calibration": (1.0, 0.0, 0.0)},
        note="edges alone, the paper's row of Fig. 7: the category preset's search without "
             "its appearance stages and without the instance model, its best probes "
             "re-ranked by coverage (SearchOptions.rerank) instead of by the HOG "
             "verification; its probability the share of the profile (the preset's "
             "calibration reads the appearance step's front/back share)"),
    Row(name="category preset: + HOG verification + box regression + nearest view", params={},
        note=f"beyond the paper: {_APPEARANCE}"),
    Row(name="category preset + moderate pruning", params={"prune": "moderate"}),
    Row(name="category preset + aggressive pruning", params={"prune": "aggressive"}),
)

# epfl-10-10 runs its preset's row unless asked for more (``--rows all``),
# to keep within 15 minutes with --jobs 2 (benchmarks/time_epfl_10_10.py).
_EPFL_10_10_DEFAULT_ROWS = (_EPFL_ROWS[1].name,)

_EPFL_PUBLISHED = """\
| method (EPFL cars 1-10 -> 11-20, full images) | median ° | mean ° | % < 45° |
|---|---|---|---|
| Ozuysal et al. 2009 | – | 46.5 | 71.2 |
| Torki & Elgammal 2011 | 11.3 | 34.0 | 80.7 |
| Teney & Piater 2013, weights + fitting | – | – | 79.7 |
| Teney et al. 2014 | 5.2 | 34.7 | – |
| He et al. 2014 | 6.2 | 15.8 | – |
| Fenzi et al. 2015 | 3.3 | 13.6 | – |
| HOG + 1-NN, given the true box (METHOD.md) | 4.0 | 33.1 | 82.9 |
| OpenCV LINE-2D, full image (METHOD.md) | 84.0 | 86.2 | 28.7 |
"""

_COIL_PUBLISHED = """\
| HOG + 1-NN on the same splits (METHOD.md) | seen median / mean ° | unseen median / mean ° |
|---|---|---|
| cars | 5.0 / 14.1 | 5.0 / 38.4 |
| boxes | 5.0 / 7.4 | 5.0 / 15.9 |
| bottles | 5.0 / 6.7 | 25.0 / 28.9 |
"""


def _find(data: Path, *candidates: str) -> Path:
    """The first of ``data/candidate`` that is a folder, or ``data`` itself."""
    for c in candidates:
        if (data / c).is_dir():
            return data / c
    return data


def _subset(ts: TrainingSet, keep: Sequence[int]) -> TrainingSet:
    idx = list(keep)
    return TrainingSet(images=tuple(ts.images[i] for i in idx), poses=ts.poses[idx],
                       boxes=None if ts.boxes is None else ts.boxes[idx],
                       masks=tuple(ts.masks[i] for i in idx),
                       instances=tuple(ts.instances[i] for i in idx), category=ts.category)


def _join(parts: Sequence[TrainingSet]) -> TrainingSet:
    boxes = [p.boxes if p.boxes is not None else np.full((len(p.images), 4), np.nan)
             for p in parts]
    return TrainingSet(images=tuple(i for p in parts for i in p.images),
                       poses=np.vstack([p.poses for p in parts]), boxes=np.vstack(boxes),
                       masks=tuple(m for p in parts for m in p.masks),
                       instances=tuple(n for p in parts for n in p.instances),
                       category=parts[0].category)


def coil_category(data: str | Path) -> Protocol:
    """COIL-100 categories (Fig. 5): seen instances on their other 54 views, unseen on all 72."""
    folder = _find(Path(data), "coil-100")
    train_az = list(range(0, 360, 20))
    other_az = [a for a in range(0, 360, 5) if a % 20]
    splits = []
    for cat, (seen, unseen, half) in COIL_CATEGORIES.items():
        train = read_coil(folder, objects=seen, azimuths_deg=train_az, category=cat)
        test_seen = read_coil(folder, objects=seen, azimuths_deg=other_az, category=cat)
        test_unseen = read_coil(folder, objects=unseen, category=cat)
        test = _join([test_seen, test_unseen])
        groups = (f"{cat} seen",) * len(test_seen.images) + \
            (f"{cat} unseen",) * len(test_unseen.images)
        splits.append(Split(name=cat, train=train, test=test, groups=groups, half_turn=half))
    return Protocol(
        name="coil-category",
        description=("COIL-100 category models (Fig. 5): toy cars (seen 6, 8, 23, 76; unseen "
                     "15, 91), boxes (seen 1, 31, 54, 79; unseen 46, 96), flat bottles (seen "
                     "13, 64; unseen 22, 33). Each category model is trained on its seen "
                     "instances' views at 0, 20, ..., 340°; seen instances are tested on their "
                     "other 54 views, unseen ones on all 72. Boxes and bottles are scored on "
                     "the half circle."),
        splits=tuple(splits), rows=_ABLATION, published=_COIL_PUBLISHED, preset="default",
        main_row=_ABLATION[5].name)


def _epfl_folder(data: str | Path) -> Path:
    return _find(Path(data), "epfl-gims08/tripod-seq", "tripod-seq")


def epfl_single(data: str | Path, *, cars: Sequence[int] = (1,)) -> Protocol:
    """Car 1 with 15, 30 and 40 evenly spaced training frames, the others tested (Fig. 6).

    ``cars`` runs the same protocol on other cars, one instance model per
    car and training-set size: cars 2-10 are the development set of the
    instance settings (``benchmarks/tune_epfl.py --protocol epfl-single``),
    so that car 1 is only ever used to report.
    """
    if not cars:
        raise ValueError("epfl-single needs at least one car")
    folder = _epfl_folder(data)
    splits = []
    for car in cars:
        seq = read_epfl(folder, cars=[car])
        n = len(seq.images)
        for k in (15, 30, 40):
            chosen = set(np.linspace(0, n, k, endpoint=False).round().astype(int).tolist())
            train_idx = sorted(chosen)
            test_idx = [i for i in range(n) if i not in chosen]
            splits.append(Split(name=f"car{car:02d}-{k}", train=_subset(seq, train_idx),
                                test=_subset(seq, test_idx), groups=(f"{k} training images",)
                                * len(test_idx)))
    which = f"car {cars[0]}" if len(cars) == 1 else "cars " + ", ".join(map(str, cars))
    return Protocol(
        name="epfl-single",
        description=(f"EPFL Multi-View Car, {which} (Fig. 6): 15, 30 and 40 evenly spaced "
                     "frames train an instance model, all other frames of the sequence are "
                     "tested, full frames (the estimator finds the car)."),
        splits=tuple(splits),
        rows=(Row(name="paper: weights + fitting", params={
                  "refine": RefineOptions(), "morph_views": False,
                  "search__viewpoint_subdivisions": 1}),
              Row(name="turntable preset: + local refinement + morphing", params={},
                  note="beyond the paper: features morphed between training views, two "
                       "probes per gap, local refinement")),
        preset="turntable", main_row="turntable preset: + local refinement + morphing")


def _epfl_split(folder: Path, train: Sequence[int], test: Sequence[int], name: str) -> Split:
    tr = read_epfl(folder, cars=train)
    te = read_epfl(folder, cars=test)
    return Split(name=name, train=tr, test=te, groups=tuple(te.instances))


def epfl_10_10(data: str | Path) -> Protocol:
    """Cars 1-10 train, 11-20 test (Fig. 7): needs the held-out images of cars 11-20.

    Raises
    ------
    FileNotFoundError
        When the images of cars 11-20 are not in ``data`` (they are a
        held-out test set, not shipped with ``../shared``).
    """
    folder = _epfl_folder(data)
    split = _epfl_split(folder, list(range(1, 11)), list(range(11, 21)), "cars01-10_to_11-20")
    return Protocol(
        name="epfl-10-10",
        description=("EPFL Multi-View Car (Fig. 7): one category model from cars 1-10 (1179 "
                     "frames), tested on the full frames of cars 11-20 (1120)."),
        splits=(split,), rows=_EPFL_ROWS, preset="category", published=_EPFL_PUBLISHED,
        main_row=_EPFL_ROWS[1].name, default_rows=_EPFL_10_10_DEFAULT_ROWS)


def epfl_cv(data: str | Path, *, cars: Sequence[int] = tuple(range(1, 11)),
            folds: int = 5) -> Protocol:
    """The 10/10 pipeline as a ``folds``-fold cross-validation within the cars present.

    The cars are cut into ``folds`` consecutive groups; each fold tests one
    group on a model of all the others. With cars 1-10 and five folds, each
    model has 8 cars, close to the 10-car model of ``epfl-10-10`` (the
    two-fold split 1-5 <-> 6-10 trained on 5 cars and overstated held-out
    accuracy). Every car is tested once.
    """
    folder = _epfl_folder(data)
    cars = list(cars)
    if not (isinstance(folds, int) and 2 <= folds <= len(cars)):
        raise ValueError(f"epfl-cv needs 2 <= folds <= the number of cars ({len(cars)}), "
                         f"got folds={folds!r}")
    groups = [list(g) for g in np.array_split(np.array(cars), folds)]
    splits = []
    for k, test in enumerate(groups, start=1):
        train = [c for c in cars if c not in test]
        cut = f"{test[0]:02d}-{test[-1]:02d}" if len(test) > 1 else f"{test[0]:02d}"
        splits.append(_epfl_split(folder, train, test, f"fold{k}_test-cars{cut}"))
    return Protocol(
        name="epfl-cv",
        description=(f"EPFL Multi-View Car, development cross-validation within cars "
                     f"{cars[0]}-{cars[-1]}, {folds} folds: each fold tests "
                     f"{len(groups[0])} cars on the full frames with a model of the other "
                     f"{len(cars) - len(groups[0])} (the pipeline of the 10/10 protocol; "
                     "cars 11-20 stay held out)."),
        splits=tuple(splits), rows=_EPFL_ROWS, preset="category", published=_EPFL_PUBLISHED,
        main_row=_EPFL_ROWS[1].name)


def coil_loio(data: str | Path) -> Protocol:
    """COIL categories, leave one instance out: every instance of Fig. 5 is unseen once.

    Each category of :data:`COIL_CATEGORIES` (its seen and unseen instances
    together) gives one split per instance: a category model of the other
    instances' views at 0, 20, ..., 340 degrees, tested on all 72 views of the
    one left out. It measures unseen instances over 16 objects instead of 6.
    """
    folder = _find(Path(data), "coil-100")
    train_az = list(range(0, 360, 20))
    splits = []
    for cat, (seen, unseen, half) in COIL_CATEGORIES.items():
        members = seen + unseen
        for obj in members:
            train = read_coil(folder, objects=[o for o in members if o != obj],
                              azimuths_deg=train_az, category=cat)
            test = read_coil(folder, objects=[obj], category=cat)
            splits.append(Split(name=f"{cat}-without-obj{obj}", train=train, test=test,
                                groups=(cat,) * len(test.images), half_turn=half))
    return Protocol(
        name="coil-loio",
        description=("COIL-100 categories of Fig. 5, leave one instance out: cars (6, 8, 15, "
                     "23, 76, 91), boxes (1, 31, 46, 54, 79, 96), flat bottles (13, 22, 33, 64). "
                     "Each instance in turn is tested on all its 72 views with a category model "
                     "of the others' views at 0, 20, ..., 340°. Boxes and bottles are scored on "
                     "the half circle."),
        splits=tuple(splits), rows=(_ABLATION[3], _ABLATION[5]), preset="default",
        main_row=_ABLATION[5].name)


def load_protocol(name: str, data: str | Path) -> Protocol:
    """The protocol called ``name`` on the data in ``data``.

    ``data`` may be the shared data folder (holding ``coil-100`` and
    ``epfl-gims08/tripod-seq``) or the dataset's own folder.

    Raises
    ------
    ValueError
        On an unknown protocol name.
    FileNotFoundError
        When the data it needs is not there (the message names the file).
    """
    builders = {"coil-category": coil_category, "coil-loio": coil_loio,
                "epfl-single": epfl_single, "epfl-10-10": epfl_10_10, "epfl-cv": epfl_cv}
    if name not in builders:
        raise ValueError(f"unknown protocol {name!r}; choose one of {', '.join(PROTOCOLS)}")
    if not Path(data).is_dir():
        raise FileNotFoundError(f"data folder not found: {data}")
    return builders[name](data)
