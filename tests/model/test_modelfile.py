"""The model file: round trip, and refusal of missing, foreign, corrupt or other-version files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from posevote.model.modelfile import FORMAT_VERSION, OLDEST_VERSION, load_model, save_model
from posevote.model.training import AppearanceModel, TrainedModel

#: A per-view array of the wrong size: refused from its declared shape, or after reading it.
SHAPES = "corrupt model file .*(inconsistent|one row per view)"
CORRUPT_SHAPES = "bad.npz: " + SHAPES


def _trained(model, **kw):
    return TrainedModel(model=model, full_model=model, viewpoint_kappa=3.0, **kw)


def _rewrite(src, dst, **changes):
    """Copy a model file with some arrays (or, as ``header=dict``, header fields) changed."""
    with np.load(src) as data:
        arrays = dict(data)
    header = json.loads(arrays["header"].tobytes())
    header.update(changes.pop("header", {}))
    arrays.update(changes)
    arrays["header"] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    np.savez(dst, **arrays)


def test_model_file_round_trip(tmp_path, toy_model):
    model = toy_model()
    save_model(tmp_path / "m.npz", _trained(model), {"max_modes": 2},
               preset={"name": "default", "overrides": {"max_modes": 2}})
    trained, params = load_model(tmp_path / "m.npz")
    assert params == {"max_modes": 2} and trained.appearance is None
    assert trained.full_model is trained.model and trained.viewpoint_kappa == 3.0
    assert np.array_equal(trained.model.xy, model.xy) and trained.model.instance_names == ("toy",)


def test_view_origins_round_trip_and_are_checked(tmp_path, toy_model):
    from dataclasses import replace

    model = toy_model()
    origin = np.arange(2.0 * model.n_views).reshape(-1, 2)
    save_model(tmp_path / "m.npz", _trained(replace(model, view_origin=origin)), {})
    np.testing.assert_array_equal(load_model(tmp_path / "m.npz")[0].model.view_origin, origin)
    save_model(tmp_path / "plain.npz", _trained(model), {})
    assert load_model(tmp_path / "plain.npz")[0].model.view_origin is None
    factor = np.column_stack([origin, np.full(model.n_views, 1.1)])
    save_model(tmp_path / "deep.npz", _trained(replace(model, view_origin=factor)), {})
    np.testing.assert_array_equal(load_model(tmp_path / "deep.npz")[0].model.view_origin, factor)
    for bad in (origin[:-1], np.full_like(origin, np.nan), factor * [1, 1, -1]):
        _rewrite(tmp_path / "m.npz", tmp_path / "bad.npz", view_origin=bad)
        with pytest.raises(ValueError, match=CORRUPT_SHAPES):
            load_model(tmp_path / "bad.npz")


def test_view_templates_round_trip_and_are_checked(tmp_path, toy_model):
    from dataclasses import replace

    model = toy_model()
    template = np.random.default_rng(0).random((model.n_views, 8, 8)).astype(np.float16)
    template[:, :2] = np.nan                       # outside the object
    cell = np.full(model.n_views, 1.5)
    save_model(tmp_path / "m.npz", _trained(replace(model, view_template=template,
                                                    view_template_cell=cell)), {})
    loaded = load_model(tmp_path / "m.npz")[0].model
    np.testing.assert_array_equal(loaded.view_template, template)
    np.testing.assert_array_equal(loaded.view_template_cell, cell)
    assert loaded.view_template.dtype == np.float16
    inf = template.copy()
    inf[0, 4, 4] = np.inf
    for bad in ({"view_template": template[:-1]}, {"view_template": template[:, :, :5]},
                {"view_template": inf}, {"view_template_cell": -cell},
                {"view_template_cell": cell[:-1]}):
        _rewrite(tmp_path / "m.npz", tmp_path / "bad.npz", **bad)
        with pytest.raises(ValueError, match=CORRUPT_SHAPES):
            load_model(tmp_path / "bad.npz")
    # One without the other.
    with np.load(tmp_path / "m.npz") as data:
        arrays = {k: data[k] for k in data.files if k != "view_template_cell"}
    np.savez(tmp_path / "half.npz", **arrays)
    with pytest.raises(ValueError, match="half.npz: " + SHAPES):
        load_model(tmp_path / "half.npz")


def test_view_outlines_round_trip_and_are_checked(tmp_path, toy_model):
    from dataclasses import replace

    from posevote.model.outline import OUTLINE_ANGLES

    model = toy_model()
    outline = np.random.default_rng(0).uniform(5.0, 20.0, (model.n_views, OUTLINE_ANGLES))
    save_model(tmp_path / "m.npz", _trained(replace(model, view_outline=outline)), {})
    np.testing.assert_array_equal(load_model(tmp_path / "m.npz")[0].model.view_outline, outline)
    nan, flat = outline.copy(), outline.copy()
    nan[0, 3] = np.nan
    flat[1] = 0.0                                       # no extent at all
    for bad in (outline[:-1], outline[:, :-1], nan, flat):
        _rewrite(tmp_path / "m.npz", tmp_path / "bad.npz", view_outline=bad)
        with pytest.raises(ValueError, match=CORRUPT_SHAPES):
            load_model(tmp_path / "bad.npz")


def test_view_lookalikes_round_trip_are_checked_and_may_be_absent(tmp_path, toy_model):
    from dataclasses import replace

    model = toy_model()
    alike = np.linspace(0.0, 1.0, model.n_views)
    save_model(tmp_path / "m.npz", _trained(replace(model, view_lookalike=alike)), {})
    np.testing.assert_array_equal(load_model(tmp_path / "m.npz")[0].model.view_lookalike, alike)
    for bad in (alike[:-1], alike + 0.5, np.where(alike > 0.5, np.nan, alike)):
        _rewrite(tmp_path / "m.npz", tmp_path / "bad.npz", view_lookalike=bad)
        with pytest.raises(ValueError, match=CORRUPT_SHAPES):
            load_model(tmp_path / "bad.npz")
    # A file of an earlier posevote: no likeness measured, none made up.
    save_model(tmp_path / "old.npz", _trained(replace(model, view_lookalike=None)), {})
    assert load_model(tmp_path / "old.npz")[0].model.view_lookalike is None


def test_model_file_errors(tmp_path, toy_model):
    with pytest.raises(FileNotFoundError, match="model file not found"):
        load_model(tmp_path / "none.npz")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"hello")
    with pytest.raises(ValueError, match="junk.npz: not a posevote model file"):
        load_model(junk)
    save_model(tmp_path / "m.npz", _trained(toy_model()), {})
    data = (tmp_path / "m.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="cut.npz: not a posevote model file"):
        load_model(tmp_path / "cut.npz")
    np.savez(tmp_path / "foreign.npz", a=np.zeros(3))
    with pytest.raises(ValueError, match="foreign.npz: not a posevote model file"):
        load_model(tmp_path / "foreign.npz")


@pytest.mark.parametrize(("version", "message"), [
    (FORMAT_VERSION + 1, "is newer than this posevote reads"),
    (OLDEST_VERSION - 1, "older posevote .* retrain"),
    ("3", "is not an integer"),
])
def test_other_format_versions_are_refused(tmp_path, toy_model, version, message):
    save_model(tmp_path / "m.npz", _trained(toy_model()), {})
    _rewrite(tmp_path / "m.npz", tmp_path / "v.npz", header={"version": version})
    with pytest.raises(ValueError, match=f"v.npz: .*{message}"):
        load_model(tmp_path / "v.npz")


def _version_5(params):
    """An estimator's parameters as version 5 wrote them (its switches by their old names)."""
    old = dict(params)
    refine, templates = old.pop("refine"), old.pop("templates")
    old.update(fitting=refine["fit"], local_refinement=refine["local"] is not None)
    if templates is not None:
        old["search"] = {**old["search"], "rerank": "template"}
    return old


@pytest.mark.parametrize(("preset", "n_instances"), [
    ("default", 1), ("cluttered", 1), ("turntable", 1), ("category", 10)])
def test_version_5_parameters_are_read_as_the_steps_they_ran(tmp_path, toy_model, preset,
                                                              n_instances):
    from posevote import PoseEstimator
    from posevote._options import params_to_json

    # Version 5 had no keypoint step.
    params = params_to_json(PoseEstimator.from_preset(preset, refine__keypoints=False)
                            .get_params(deep=False))
    save_model(tmp_path / "m.npz", _trained(toy_model()), _version_5(params))
    _rewrite(tmp_path / "m.npz", tmp_path / "v5.npz", header={"version": 5})
    from posevote.model import modelfile

    assert modelfile._version_5_params(_version_5(params), n_instances) == params
    _, read = load_model(tmp_path / "v5.npz")
    if n_instances == 1:
        assert read == params


def test_bad_arrays_and_header_values_are_refused(tmp_path, toy_model):
    model = toy_model()
    save_model(tmp_path / "m.npz", _trained(model), {})
    xy = model.xy.copy()
    xy[0, 0] = np.nan
    cases = [({"xy": xy}, "array xy has values that are not finite"),
             ({"view_box": np.zeros_like(model.view_box)}, "view_box has boxes of zero size"),
             ({"header": {"instance_size": [1.0, -2.0]}}, r"instance_size"),
             ({"header": {"extra": {"viewpoint_kappa": "x"}}}, "viewpoint_kappa")]
    for changes, message in cases:
        _rewrite(tmp_path / "m.npz", tmp_path / "bad.npz", **changes)
        with pytest.raises(ValueError, match=f"bad.npz: corrupt model file .*{message}"):
            load_model(tmp_path / "bad.npz")


def test_appearance_arrays_round_trip_and_are_checked(tmp_path, toy_model):
    model = toy_model()
    window = (48, 48)
    from posevote.features.hog import descriptor_length

    length = descriptor_length(window)
    look = AppearanceModel(window=window, descriptors=np.ones((3, length), np.float32),
                           objectness=np.zeros(length + 1), regressor=np.zeros((8, 4, length + 1)))
    save_model(tmp_path / "m.npz", _trained(model, appearance=look), {})
    trained, _ = load_model(tmp_path / "m.npz")
    assert trained.appearance is not None and trained.appearance.window == window
    np.testing.assert_array_equal(trained.appearance.descriptors, look.descriptors)
    for name, bad in (("box_regressor", np.zeros((8, 3, 5))),
                      ("box_regressor", np.full((8, 4, length + 1), np.nan)),
                      ("objectness", np.zeros(3)),
                      ("view_descriptor", np.ones((2, length), np.float32))):
        _rewrite(tmp_path / "m.npz", tmp_path / "bad.npz", **{name: bad})
        with pytest.raises(ValueError, match=f"bad.npz: corrupt model file \\((array )?{name}"):
            load_model(tmp_path / "bad.npz")


def test_shrunk_models_round_trip_and_are_checked(tmp_path, toy_model):
    from dataclasses import replace

    model = toy_model()
    small = _trained(replace(model, xy=model.xy / 2))
    save_model(tmp_path / "m.npz", _trained(model, shrunk=((1.8, small),)), {})
    [(level, read)] = load_model(tmp_path / "m.npz")[0].shrunk
    assert level == 1.8 and read.shrunk == ()
    np.testing.assert_array_equal(read.model.xy, model.xy / 2)
    assert load_model(tmp_path / "m.npz")[0].model.xy.tolist() == model.xy.tolist()
    for header in ({"levels": []}, {"levels": [0.5]}, {"levels": ["x"]}):
        with np.load(tmp_path / "m.npz") as data:
            extra = json.loads(data["header"].tobytes())["extra"]
        _rewrite(tmp_path / "m.npz", tmp_path / "bad.npz", header={"extra": {**extra, **header}})
        with pytest.raises(ValueError, match="bad.npz: corrupt model file .*levels"):
            load_model(tmp_path / "bad.npz")
    # A shrunk model's own bytes, corrupt: named as the file's level model.
    _rewrite(tmp_path / "m.npz", tmp_path / "bad.npz",
             level_model_0=np.frombuffer(b"not an archive", dtype=np.uint8))
    with pytest.raises(ValueError, match=r"bad.npz \(its level 1.8 model\): not a posevote"):
        load_model(tmp_path / "bad.npz")
