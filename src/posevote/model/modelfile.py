"""The model file: versioned, self-describing, loaded without pickle.

A model file is a NumPy ``.npz`` archive of plain numeric arrays plus one
``header`` entry: UTF-8 JSON with ``format`` (``"posevote-model"``),
``version`` (an integer), the estimator's hyper-parameters and the model's
names. ``allow_pickle`` is never enabled, so loading a file cannot run code.

Version 2 adds the optional ``full_*`` arrays: the unpruned model of a
pruned category model (for instance recognition and refinement). Version 1
files are still read. The optional ``view_descriptor`` array (one appearance
descriptor per training view, for ``verify_candidates``) and ``objectness``
array (the verification's classifier) are additions that version-2 readers
ignore, so they keep the version number; so is the header's optional
``instance_size`` (each instance's training size relative to the reference,
for ``instance_search``; files without it read as all 1), and the optional
``shift`` and ``view_neighbour`` arrays (the morphing between turntable
views, ``morph_views``; files without them are not morphed), and the
optional ``box_regressor`` array (the box regressions of
``appearance_refine``, one ``(4, D + 1)`` block of weights and intercepts
per azimuth range).
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from posevote._io import atomic_open
from posevote.model.density import PoseModel

FORMAT_NAME = "posevote-model"
FORMAT_VERSION = 2

_FEATURE_ARRAYS = ("xy", "theta", "view", "weight")
_ARRAYS = (*_FEATURE_ARRAYS, "view_azimuth", "view_elevation", "view_box", "view_instance")
_MORPH_ARRAYS = ("shift", "view_neighbour")


def save_model(path: str | Path, model: PoseModel, params: dict[str, Any],
               extra: dict[str, Any] | None = None, full_model: PoseModel | None = None,
               descriptors: np.ndarray | None = None, objectness: np.ndarray | None = None,
               box_regressor: np.ndarray | None = None) -> None:
    """Write a model file atomically.

    Parameters
    ----------
    path : str or Path
        Destination (conventionally ``*.npz``).
    model : PoseModel
        The trained model.
    params : dict
        Estimator hyper-parameters (JSON-serialisable).
    extra : dict, optional
        Further JSON-serialisable facts to record (training statistics).
    full_model : PoseModel, optional
        The unpruned model, when ``model`` is pruned (same views).
    descriptors : ndarray, shape (K, D), optional
        Appearance descriptor of each training view.
    objectness : ndarray, shape (D + 1,), optional
        The verification's linear object/background classifier.
    box_regressor : ndarray, shape (B, 4, D + 1), optional
        The box regressions of ``appearance_refine``.
    """
    header = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "params": params,
        "instance_names": list(model.instance_names),
        "reference_size": model.reference_size,
        "category": model.category,
        "instance_size": list(model.instance_size),
        "extra": extra or {},
    }
    arrays = {name: getattr(model, name) for name in _ARRAYS}
    for name in _MORPH_ARRAYS:
        if getattr(model, name) is not None:
            arrays[name] = getattr(model, name)
    if full_model is not None:
        arrays.update({f"full_{name}": getattr(full_model, name) for name in _FEATURE_ARRAYS})
        if full_model.shift is not None:
            arrays["full_shift"] = full_model.shift
    if descriptors is not None:
        arrays["view_descriptor"] = np.asarray(descriptors, dtype=np.float32)
    if objectness is not None:
        arrays["objectness"] = np.asarray(objectness, dtype=np.float64)
    if box_regressor is not None:
        arrays["box_regressor"] = np.asarray(box_regressor, dtype=np.float64)
    arrays["header"] = np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8)
    with atomic_open(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)


def load_model(path: str | Path
               ) -> tuple[PoseModel, dict[str, Any], dict[str, Any], PoseModel | None,
                          np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """Read a model file.

    Parameters
    ----------
    path : str or Path
        A file written by :func:`save_model`.

    Returns
    -------
    model : PoseModel
    params : dict
        The estimator hyper-parameters it was trained with.
    extra : dict
        Recorded training facts.
    full_model : PoseModel or None
        The unpruned model, if the file has one.
    descriptors : ndarray of float32, shape (K, D), or None
        The training views' appearance descriptors, if the file has them.
    objectness : ndarray, shape (D + 1,), or None
        The verification's object/background classifier, if the file has it.
    box_regressor : ndarray, shape (B, 4, D + 1), or None
        The box regressions of ``appearance_refine``, if the file has them.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If it is not a posevote model, is truncated or corrupt, or was written
        by a newer format version than this posevote reads.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"model file not found: {path}")
    if not zipfile.is_zipfile(path):
        raise ValueError(f"{path}: not a posevote model file (not an .npz archive, or truncated)")
    try:
        with np.load(path, allow_pickle=False) as data:
            if "header" not in data.files:
                raise ValueError(f"{path}: not a posevote model file (no header)")
            header = json.loads(bytes(data["header"]).decode("utf-8"))
            if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
                raise ValueError(f"{path}: not a posevote model file")
            version = header.get("version")
            if not isinstance(version, int) or version > FORMAT_VERSION:
                raise ValueError(
                    f"{path}: model format version {version} is newer than this posevote reads "
                    f"(up to {FORMAT_VERSION}); upgrade posevote or retrain the model")
            arrays = {name: data[name] for name in _ARRAYS}
            arrays.update({name: data[name] for name in _MORPH_ARRAYS if name in data.files})
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
    except ValueError as exc:
        if str(exc).startswith(str(path)):
            raise
        raise ValueError(f"{path}: corrupt or truncated model file ({exc})") from None
    except (zipfile.BadZipFile, OSError, KeyError, EOFError, json.JSONDecodeError,
            UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a posevote model file, or truncated/corrupt "
                         f"({type(exc).__name__}: {exc})") from None
    model = _build(path, arrays, header)
    full_model = None
    if full is not None:
        full_model = _build(path, {**arrays, **full}, header)
    if descriptors is not None and (descriptors.ndim != 2
                                    or descriptors.shape[0] != model.n_views):
        raise ValueError(f"{path}: corrupt model file (view_descriptor has shape "
                         f"{descriptors.shape} for {model.n_views} views)")
    if regressor is not None and (regressor.ndim != 3 or regressor.shape[1] != 4
                                  or not np.all(np.isfinite(regressor))):
        raise ValueError(f"{path}: corrupt model file (box_regressor has shape "
                         f"{regressor.shape}, or values that are not finite)")
    return (model, dict(header.get("params", {})), dict(header.get("extra", {})), full_model,
            descriptors, objectness, regressor)


def _build(path: Path, arrays: dict[str, np.ndarray], header: dict[str, Any]) -> PoseModel:
    """A PoseModel from the file's arrays, after checking their shapes."""
    m = len(arrays["theta"])
    k = len(arrays["view_azimuth"])
    shapes_ok = (arrays["xy"].shape == (m, 2) and arrays["view"].shape == (m,)
                 and arrays["weight"].shape == (m,) and arrays["view_box"].shape == (k, 2)
                 and arrays["view_elevation"].shape == (k,) and arrays["view_instance"].shape == (k,)
                 and (m == 0 or (arrays["view"].min() >= 0 and arrays["view"].max() < k)))
    shift, neighbour = arrays.get("shift"), arrays.get("view_neighbour")
    if shift is not None or neighbour is not None:
        # The morphing arrays come together, one displacement pair per feature.
        shapes_ok = (shapes_ok and shift is not None and neighbour is not None
                     and shift.shape == (m, 2, 2) and neighbour.shape == (k, 2)
                     and bool(np.all(np.isfinite(shift)))
                     and bool(np.all((neighbour >= -1) & (neighbour < k))))
    if not shapes_ok:
        raise ValueError(f"{path}: corrupt model file (inconsistent array shapes)")
    names = tuple(header.get("instance_names", []))
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
    )
