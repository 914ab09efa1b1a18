"""The model file: versioned, self-describing, loaded without pickle.

A model file is a NumPy ``.npz`` archive of plain numeric arrays plus one
``header`` entry: UTF-8 JSON with ``format`` (``"posevote-model"``),
``version`` (an integer), the estimator's parameters (``params``, option
groups as objects of their fields), the preset they come from with the
parameters that differ from it (``preset``: ``{"name", "overrides"}``, or
null), the model's names and training facts (``extra``: the pose kernel's
concentration, the pruning knobs, the descriptor window, the object's
height in metres or null).
``allow_pickle`` is never enabled, so loading a file cannot run code.

Arrays: the features (``xy``, ``theta``, ``view``, ``weight``) and views
(``view_azimuth``, ``view_elevation``, ``view_box``, ``view_instance``) of
the searched model; ``full_*`` feature arrays when it is pruned (the full
model, for recognition and refinement); ``shift`` and ``view_neighbour``
for morphed models; ``view_origin`` when training gave the object's origin;
``view_template`` (float16, NaN outside the object) and
``view_template_cell``, the views' grey templates; ``view_outline`` when
training gave masks; ``view_lookalike``, how alike each view is to another
side (absent from files of an earlier posevote: no view is then taken for
another side);
``view_descriptor``, ``objectness`` and ``box_regressor`` for the
appearance stages; ``keypoint_xy``, ``keypoint_descriptor`` (uint8) and
``keypoint_view`` for the keypoint step; ``level_model_0``, ``level_model_1``, ...
(uint8), each the bytes of a model file of its own without parameters, the
model of the views shrunk by the image level over 1 at the same place in the
header's ``extra.levels``. Versions 5 and 6 are read: version 5 named the
refinement steps' switches ``fitting`` and ``local_refinement`` and the
template steps ``search.rerank = "template"``; its parameters are read as
the same steps' switches (:func:`_version_5_params`). Files of versions 1-4
name parameters that no longer exist or hold no templates, and must be
retrained.
"""

from __future__ import annotations

import io
import json
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from posevote._io import atomic_open, parse_json
from posevote.camera import check_object_height
from posevote.features.hog import descriptor_length
from posevote.model.density import PoseModel
from posevote.model.outline import OUTLINE_ANGLES
from posevote.model.training import MAX_LEVEL, AppearanceModel, TrainedModel

FORMAT_NAME = "posevote-model"
FORMAT_VERSION = 6
#: The oldest version read (its parameters translated).
OLDEST_VERSION = 5

#: A model file larger than this (bytes) is refused before it is read.
MAX_MODEL_BYTES = 2 << 30
#: The most features and views a model file may declare (each array is
#: checked against these before it is decompressed).
MAX_FEATURES = 50_000_000
MAX_VIEWS = 1_000_000

_FEATURE_ARRAYS = ("xy", "theta", "view", "weight")
_ARRAYS = (*_FEATURE_ARRAYS, "view_azimuth", "view_elevation", "view_box", "view_instance")
_MORPH_ARRAYS = ("shift", "view_neighbour")
#: Optional per-view arrays, written when the model has them.
_VIEW_OPTIONAL = ("view_origin", "view_template", "view_template_cell", "view_outline",
                  "view_lookalike")
#: The views' keypoints, written when the model has them (the searched and full models share
#: them).
_KEYPOINT_ARRAYS = ("keypoint_xy", "keypoint_descriptor", "keypoint_view")


def save_model(path: str | Path, trained: TrainedModel, params: dict[str, Any], *,
               preset: dict[str, Any] | None = None) -> None:
    """Write a model file atomically.

    Parameters
    ----------
    path : str or Path
        Destination (conventionally ``*.npz``).
    trained : TrainedModel
        What was learnt.
    params : dict
        Estimator parameters, JSON-ready.
    preset : dict, optional
        ``{"name": ..., "overrides": {...}}``: the preset the parameters
        come from and what differs from it.
    """
    arrays = _arrays(trained, params, preset)
    with atomic_open(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)


def _arrays(trained: TrainedModel, params: dict[str, Any], preset: dict[str, Any] | None
            ) -> dict[str, Any]:
    """What a model file holds, by array name; each shrunk model as a model file of its own
    (its bytes), ``level_model_<i>``."""
    model, full = trained.model, trained.full_model
    header = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "params": params,
        "preset": preset,
        "instance_names": list(model.instance_names),
        "reference_size": model.reference_size,
        "category": model.category,
        "instance_size": list(model.instance_size),
        "extra": {"viewpoint_kappa": trained.viewpoint_kappa, "pruning": trained.pruning,
                  "object_height_m": trained.object_height_m,
                  "descriptor_window": None if trained.appearance is None
                  else list(trained.appearance.window),
                  "levels": [level for level, _ in trained.shrunk]},
    }
    arrays = {name: getattr(model, name) for name in _ARRAYS}
    for name in (*_MORPH_ARRAYS, *_VIEW_OPTIONAL, *_KEYPOINT_ARRAYS):
        if getattr(model, name) is not None:
            arrays[name] = getattr(model, name)
    if full is not model:
        arrays.update({f"full_{name}": getattr(full, name) for name in _FEATURE_ARRAYS})
        if full.shift is not None:
            arrays["full_shift"] = full.shift
    look = trained.appearance
    if look is not None:
        arrays["view_descriptor"] = np.asarray(look.descriptors, dtype=np.float32)
        if look.objectness is not None:
            arrays["objectness"] = np.asarray(look.objectness, dtype=np.float64)
        if look.regressor is not None:
            arrays["box_regressor"] = np.asarray(look.regressor, dtype=np.float64)
    for i, (_, small) in enumerate(trained.shrunk):
        packed = io.BytesIO()
        np.savez_compressed(packed, **_arrays(small, {}, None))
        arrays[f"level_model_{i}"] = np.frombuffer(packed.getvalue(), dtype=np.uint8)
    arrays["header"] = np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8)
    return arrays


def load_model(path: str | Path) -> tuple[TrainedModel, dict[str, Any]]:
    """Read a model file.

    Parameters
    ----------
    path : str or Path
        A file written by :func:`save_model`.

    Returns
    -------
    trained : TrainedModel
    params : dict
        The estimator parameters it was trained with (JSON form).

    Raises
    ------
    TypeError
        If ``path`` is not a str or Path.
    FileNotFoundError
        If the file does not exist.
    ValueError
        If it is not a posevote model, is truncated or corrupt (arrays of the
        wrong shape or type, values that are not finite, zero boxes, header
        fields of the wrong type), is past the size limits, or was written
        by another format version than this posevote reads. The message
        names the file and the array or field.
    """
    if not isinstance(path, (str, Path)):
        raise TypeError(f"path must be a str or Path, got {type(path).__name__}")
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"model file not found: {path}")
    size = path.stat().st_size
    if size > MAX_MODEL_BYTES:
        raise ValueError(f"{path}: {size:,} bytes, over the limit of {MAX_MODEL_BYTES:,} for a "
                         "model file")
    if not zipfile.is_zipfile(path):
        raise ValueError(f"{path}: not a posevote model file (not an .npz archive, or truncated)")
    return _read(str(path), path)


def _read(path: str, source: Path | io.BytesIO, *, nested: bool = False
          ) -> tuple[TrainedModel, dict[str, Any]]:
    """:func:`load_model` of ``source`` (a file, or a shrunk model's bytes: ``nested``, which
    holds none of its own), ``path`` naming it in errors."""
    if nested and not zipfile.is_zipfile(source):
        raise ValueError(f"{path}: not a posevote model file (not an .npz archive, or truncated)")
    packed: list[NDArray[np.uint8]] = []
    try:
        with np.load(source, allow_pickle=False) as data:
            if "header" not in data.files:
                raise ValueError(f"{path}: not a posevote model file (no header)")
            header = parse_json(bytes(data["header"]).decode("utf-8"), f"{path}: header")
            if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
                raise ValueError(f"{path}: not a posevote model file")
            version = header.get("version")
            if not isinstance(version, int) or isinstance(version, bool):
                raise ValueError(f"{path}: corrupt model file (format version {version!r} "
                                 "is not an integer)")
            if version > FORMAT_VERSION:
                raise ValueError(
                    f"{path}: model format version {version} is newer than this posevote reads "
                    f"({FORMAT_VERSION}); upgrade posevote or retrain the model")
            if version < OLDEST_VERSION:
                raise ValueError(
                    f"{path}: model format version {version} was written by an older posevote "
                    f"(this one reads {OLDEST_VERSION}-{FORMAT_VERSION}); retrain the model")
            missing = [name for name in _ARRAYS if name not in data.files]
            if missing:
                raise ValueError(f"{path}: corrupt model file (missing array(s) "
                                 f"{', '.join(missing)})")
            _check_sizes(path, data)
            arrays = {name: data[name] for name in _ARRAYS}
            arrays.update({name: data[name]
                           for name in (*_MORPH_ARRAYS, *_VIEW_OPTIONAL, *_KEYPOINT_ARRAYS)
                           if name in data.files})
            full = ({name: data[f"full_{name}"] for name in _FEATURE_ARRAYS}
                    if "full_xy" in data.files else None)
            if full is not None:
                morphed = "full_shift" in data.files and "shift" in arrays
                full["shift"] = data["full_shift"] if morphed else None
                full["view_neighbour"] = arrays["view_neighbour"] if morphed else None
            descriptors = (data["view_descriptor"].astype(np.float32)
                           if "view_descriptor" in data.files else None)
            objectness = (data["objectness"].astype(np.float64)
                          if "objectness" in data.files else None)
            regressor = (data["box_regressor"].astype(np.float64)
                         if "box_regressor" in data.files else None)
            while f"level_model_{len(packed)}" in data.files:
                packed.append(data[f"level_model_{len(packed)}"])
    except ValueError as exc:
        if str(exc).startswith(str(path)):
            raise
        raise ValueError(f"{path}: corrupt or truncated model file ({exc})") from None
    except (zipfile.BadZipFile, OSError, KeyError, EOFError, json.JSONDecodeError,
            UnicodeDecodeError, zlib.error) as exc:
        raise ValueError(f"{path}: not a posevote model file, or truncated/corrupt "
                         f"({type(exc).__name__}: {exc})") from None
    _check_header(path, header)
    model = _build(path, arrays, header)
    full_model = None
    if full is not None:
        full_model = _build(path, {**arrays, **full}, header)
    extra = header.get("extra", {})
    params = header.get("params", {})
    if not isinstance(extra, dict) or not isinstance(params, dict):
        raise ValueError(f"{path}: corrupt model file (params and extra must be objects)")
    look = None
    if descriptors is not None:
        window = extra.get("descriptor_window")
        if not (isinstance(window, list) and len(window) == 2
                and all(isinstance(n, int) and 8 <= n <= 1024 for n in window)):
            raise ValueError(f"{path}: corrupt model file (descriptor_window {window!r})")
        win = (int(window[0]), int(window[1]))
        length = descriptor_length(win)
        if descriptors.shape != (model.n_views, length) or not np.all(np.isfinite(descriptors)):
            raise ValueError(f"{path}: corrupt model file (view_descriptor has shape "
                             f"{descriptors.shape} for {model.n_views} views of length {length},"
                             " or values that are not finite)")
        if objectness is not None and (objectness.shape != (length + 1,)
                                       or not np.all(np.isfinite(objectness))):
            raise ValueError(f"{path}: corrupt model file (objectness has shape "
                             f"{objectness.shape}, or values that are not finite)")
        if regressor is not None and (regressor.ndim != 3 or regressor.shape[1:] != (4, length + 1)
                                      or not np.all(np.isfinite(regressor))):
            raise ValueError(f"{path}: corrupt model file (box_regressor has shape "
                             f"{regressor.shape}, or values that are not finite)")
        look = AppearanceModel(window=win, descriptors=descriptors, objectness=objectness,
                               regressor=regressor)
    kappa = extra.get("viewpoint_kappa")
    if not (isinstance(kappa, (int, float)) and not isinstance(kappa, bool)
            and np.isfinite(kappa) and kappa > 0):
        raise ValueError(f"{path}: corrupt model file (viewpoint_kappa {kappa!r})")
    pruning = extra.get("pruning")
    try:
        height = check_object_height(extra.get("object_height_m"))
    except ValueError as exc:
        raise ValueError(f"{path}: corrupt model file ({exc})") from None
    levels = extra.get("levels", [])
    if not (isinstance(levels, list) and len(levels) == len(packed) and not (nested and levels)
            and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                    and 1.0 < v <= MAX_LEVEL for v in levels)):
        raise ValueError(f"{path}: corrupt model file (levels {levels!r} for {len(packed)} "
                         "shrunk models)")
    shrunk = tuple((float(level), _read(f"{path} (its level {level:g} model)",
                                        io.BytesIO(arr.tobytes()), nested=True)[0])
                   for level, arr in zip(levels, packed, strict=True))
    trained = TrainedModel(model=model, full_model=model if full_model is None else full_model,
                           viewpoint_kappa=float(kappa), appearance=look,
                           pruning=pruning if isinstance(pruning, dict) else None,
                           object_height_m=height, shrunk=shrunk)
    if header["version"] == 5:
        params = _version_5_params(params, len(model.instance_names))
    return trained, dict(params)


def _version_5_params(params: dict[str, Any], n_instances: int) -> dict[str, Any]:
    """A version-5 file's parameters as the switches of the steps it ran.

    Version 5 ran the rescale step when fitting without the local refinement or
    the appearance stages, the local refinement's profile when fitting (else a
    polish), the outline without the appearance stages, and the half-turn and
    share-scale steps with the template re-ranking and the local refinement
    where no instance was to be recognised, and no keypoint step.
    """
    out = dict(params)
    fitting, local = out.pop("fitting", True), out.pop("local_refinement", False)
    search = dict(out.get("search") or {})
    template = search.get("rerank") == "template"
    if template:
        search["rerank"] = None
    if "search" in out:
        out["search"] = search
    looks = out.get("appearance") is not None
    recognising = out.get("recognition", {}) is not None and n_instances > 1
    out["refine"] = {"fit": fitting, "rescale": bool(fitting and not local and not looks),
                     "local": ("profile" if fitting else "polish") if local else None,
                     "share_scale": bool(template and local and not recognising),
                     "outline": not looks, "keypoints": False}
    out["templates"] = {"rerank": True, "weigh": True,
                        "half_turn": bool(local and not recognising)} if template else None
    return out


def _check_sizes(path: str, data: Any) -> None:
    """Refuse arrays whose declared size, shape or type is past the limits or does not fit
    the others', before decompressing any of them."""
    declared: dict[str, tuple[tuple[int, ...], np.dtype]] = {}
    for name in data.files:
        with data.zip.open(f"{name}.npy") as fh:
            try:
                version = np.lib.format.read_magic(fh)
                read = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                        else np.lib.format.read_array_header_2_0)
                shape, _, dtype = read(fh)
            except ValueError as exc:
                raise ValueError(f"{path}: corrupt model file (array {name}: {exc})") from None
        n = int(np.prod(shape, dtype=np.float64)) if shape else 1
        if dtype.hasobject or n * dtype.itemsize > MAX_MODEL_BYTES * 4 \
                or (name in ("theta", "full_theta", "keypoint_view") and n > MAX_FEATURES) \
                or (name == "view_azimuth" and n > MAX_VIEWS):
            raise ValueError(f"{path}: corrupt model file (array {name} declares shape {shape} "
                             f"of {dtype}, past the limits)")
        if dtype.kind not in "biuf":
            raise ValueError(f"{path}: corrupt model file (array {name} holds {dtype}, not "
                             "real numbers)")
        declared[name] = (tuple(shape), dtype)

    def refuse(name: str, expected: str) -> None:
        shape, dtype = declared[name]
        raise ValueError(f"{path}: corrupt model file (array {name} declares shape {shape} of "
                         f"{dtype}; expected {expected})")

    for prefix in ("", "full_"):
        if f"{prefix}theta" not in declared:
            continue
        if len(declared[f"{prefix}theta"][0]) != 1:
            refuse(f"{prefix}theta", "one angle per feature")
        m = declared[f"{prefix}theta"][0][0]
        for name, shape in (("xy", (m, 2)), ("view", (m,)), ("weight", (m,))):
            if f"{prefix}{name}" in declared and declared[f"{prefix}{name}"][0] != shape:
                refuse(f"{prefix}{name}", f"shape {shape}, as {prefix}theta's {m} features")
        if f"{prefix}view" in declared and declared[f"{prefix}view"][1].kind not in "iu":
            refuse(f"{prefix}view", "whole numbers (view indices)")
    if "view_azimuth" in declared:
        if len(declared["view_azimuth"][0]) != 1:
            refuse("view_azimuth", "one azimuth per view")
        k = declared["view_azimuth"][0][0]
        for name, (shape, _) in declared.items():
            # A per-view array holds at most a template's worth of numbers per view.
            if name.startswith("view_") and (not shape or shape[0] != k
                                            or np.prod(shape, dtype=np.float64) > k * 65536):
                refuse(name, f"one row per view ({k}), of at most 65536 numbers")
    if "header" in declared and np.prod(declared["header"][0], dtype=np.float64) > 16 << 20:
        refuse("header", "at most 16 MiB of JSON")


def _check_header(path: str, header: dict[str, Any]) -> None:
    """The header's fields have the types :func:`_build` reads."""
    names = header.get("instance_names", [])
    if not (isinstance(names, list) and all(isinstance(n, str) for n in names)):
        raise ValueError(f"{path}: corrupt model file (header instance_names must be a list "
                         f"of strings, got {names!r})")
    ref = header.get("reference_size", 1.0)
    if not (isinstance(ref, (int, float)) and not isinstance(ref, bool) and np.isfinite(ref)
            and ref > 0):
        raise ValueError(f"{path}: corrupt model file (header reference_size must be a "
                         f"positive number, got {ref!r})")
    if not isinstance(header.get("category", ""), str):
        raise ValueError(f"{path}: corrupt model file (header category must be a string)")


#: The largest magnitude each array may hold: angles within two turns (radians), pixels
#: and weights within a million.
_BOUNDS = {"xy": 1e6, "theta": 4 * np.pi, "weight": 1e6, "view_azimuth": 4 * np.pi,
           "view_elevation": np.pi, "view_box": 1e6}


def _build(path: str, arrays: dict[str, np.ndarray], header: dict[str, Any]) -> PoseModel:
    """A PoseModel from the file's arrays, after checking their shapes."""
    m = len(arrays["theta"])
    k = len(arrays["view_azimuth"])
    shapes_ok = (arrays["xy"].shape == (m, 2) and arrays["view"].shape == (m,)
                 and arrays["weight"].shape == (m,) and arrays["view_box"].shape == (k, 2)
                 and arrays["view_elevation"].shape == (k,) and arrays["view_instance"].shape == (k,)
                 and (m == 0 or (arrays["view"].min() >= 0 and arrays["view"].max() < k))
                 and all(np.issubdtype(arrays[n].dtype, np.number) for n in _ARRAYS))
    shift, neighbour = arrays.get("shift"), arrays.get("view_neighbour")
    if shift is not None or neighbour is not None:
        # The morphing arrays come together, one displacement per feature and neighbour
        # (two on a turntable, four over the sphere).
        shapes_ok = (shapes_ok and shift is not None and neighbour is not None
                     and neighbour.ndim == 2 and neighbour.shape[0] == k
                     and neighbour.shape[1] in (2, 4) and shift.shape == (m, neighbour.shape[1], 2)
                     and bool(np.all(np.isfinite(shift)))
                     and bool(np.all((neighbour >= -1) & (neighbour < k))))
    origin = arrays.get("view_origin")
    if origin is not None:
        shapes_ok = (shapes_ok and origin.ndim == 2 and origin.shape[0] == k
                     and origin.shape[1] in (2, 3)
                     and np.issubdtype(origin.dtype, np.number)
                     and bool(np.all(np.isfinite(origin)))
                     and bool(np.all(origin[:, 2:] > 0)))
    template, cell = arrays.get("view_template"), arrays.get("view_template_cell")
    if template is not None or cell is not None:
        # Together, one square template and one positive pixel size per view.
        shapes_ok = (shapes_ok and template is not None and cell is not None
                     and template.ndim == 3 and template.shape[0] == k
                     and template.shape[1] == template.shape[2]
                     and np.issubdtype(template.dtype, np.floating)
                     and not np.any(np.isinf(template))
                     and cell.shape == (k,) and np.issubdtype(cell.dtype, np.number)
                     and bool(np.all(np.isfinite(cell) & (cell > 0))))
    outline = arrays.get("view_outline")
    if outline is not None:
        # One support function per view, of an outline with some extent across every direction.
        shapes_ok = (shapes_ok and outline.shape == (k, OUTLINE_ANGLES)
                     and np.issubdtype(outline.dtype, np.number)
                     and bool(np.all(np.isfinite(outline)))
                     and bool(np.all(outline + np.roll(outline, OUTLINE_ANGLES // 2, axis=1) > 0)))
    lookalike = arrays.get("view_lookalike")
    if lookalike is not None:
        # One share per view.
        shapes_ok = (shapes_ok and lookalike.shape == (k,)
                     and np.issubdtype(lookalike.dtype, np.number)
                     and bool(np.all((lookalike >= 0) & (lookalike <= 1))))
    kp_xy, kp_desc, kp_view = (arrays.get(name) for name in _KEYPOINT_ARRAYS)
    if kp_xy is not None or kp_desc is not None or kp_view is not None:
        # Together: a position, a SIFT descriptor of bytes and a view per keypoint.
        shapes_ok = (shapes_ok and kp_xy is not None and kp_desc is not None
                     and kp_view is not None and kp_view.ndim == 1
                     and kp_xy.shape == (len(kp_view), 2) and kp_desc.shape == (len(kp_view), 128)
                     and kp_desc.dtype == np.uint8 and kp_view.dtype.kind in "iu"
                     and np.issubdtype(kp_xy.dtype, np.floating)
                     and bool(np.all(np.isfinite(kp_xy)))
                     and (kp_xy.size == 0 or float(np.abs(kp_xy).max()) <= 1e6)
                     and (kp_view.size == 0 or (kp_view.min() >= 0 and kp_view.max() < k)))
    if not shapes_ok:
        raise ValueError(f"{path}: corrupt model file (inconsistent array shapes)")
    for name in ("xy", "theta", "weight", "view_azimuth", "view_elevation", "view_box"):
        if not np.all(np.isfinite(arrays[name])):
            raise ValueError(f"{path}: corrupt model file (array {name} has values that are "
                             "not finite)")
        # Finite but absurd (angles in other units, pixels past any image): corrupt as well.
        bound = _BOUNDS[name]
        if arrays[name].size and float(np.abs(arrays[name]).max()) > bound:
            raise ValueError(f"{path}: corrupt model file (array {name} has values past "
                             f"{bound:g})")
    if np.any(arrays["view_box"] <= 0):
        raise ValueError(f"{path}: corrupt model file (array view_box has boxes of zero size)")
    if np.any(arrays["weight"] < 0):
        raise ValueError(f"{path}: corrupt model file (array weight has negative weights)")
    names = tuple(header.get("instance_names", []))
    if k and (arrays["view_instance"].min() < 0
              or arrays["view_instance"].max() >= max(len(names), 1)):
        raise ValueError(f"{path}: corrupt model file (array view_instance names instances "
                         f"beyond the header's {len(names)} instance_names)")
    size = header.get("instance_size", [])
    if not (isinstance(size, list) and (not size or len(size) == len(names))
            and all(isinstance(f, (int, float)) and np.isfinite(f) and f > 0 for f in size)):
        raise ValueError(f"{path}: corrupt model file (instance_size must list one positive "
                         f"number per instance)")
    return PoseModel(
        xy=arrays["xy"].astype(np.float64), theta=arrays["theta"].astype(np.float64),
        view=arrays["view"].astype(np.int64), weight=arrays["weight"].astype(np.float64),
        view_azimuth=arrays["view_azimuth"].astype(np.float64),
        view_elevation=arrays["view_elevation"].astype(np.float64),
        view_box=arrays["view_box"].astype(np.float64),
        view_instance=arrays["view_instance"].astype(np.int64),
        instance_names=names,
        reference_size=float(header.get("reference_size", 1.0)),
        category=str(header.get("category", "")),
        instance_size=tuple(float(f) for f in size),
        shift=None if shift is None else shift.astype(np.float64),
        view_neighbour=None if neighbour is None else neighbour.astype(np.int64),
        view_origin=None if origin is None else origin.astype(np.float64),
        view_template=None if template is None else template.astype(np.float16),
        view_template_cell=None if cell is None else cell.astype(np.float64),
        view_outline=None if outline is None else outline.astype(np.float64),
        view_lookalike=None if lookalike is None else lookalike.astype(np.float64),
        keypoint_xy=None if kp_xy is None else kp_xy.astype(np.float64),
        keypoint_descriptor=kp_desc,
        keypoint_view=None if kp_view is None else kp_view.astype(np.int64),
    )
