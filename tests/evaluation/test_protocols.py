import pytest

from posevote.evaluation.protocols import PROTOCOLS, epfl_cv, epfl_single, load_protocol


def test_unknown_protocol_and_missing_data(tmp_path):
    with pytest.raises(ValueError, match="unknown protocol 'x'"):
        load_protocol("x", tmp_path)
    with pytest.raises(FileNotFoundError, match="data folder not found"):
        load_protocol("coil-category", tmp_path / "nothing")
    with pytest.raises(FileNotFoundError):
        load_protocol("epfl-cv", tmp_path)


def test_coil_category_splits(coil_dir):
    proto = load_protocol("coil-category", coil_dir.parent)
    assert [s.name for s in proto.splits] == ["cars", "boxes", "bottles"]
    cars = proto.splits[0]
    assert len(cars.train.images) == 4 * 18
    assert cars.groups.count("cars seen") == 4 * 54 and cars.groups.count("cars unseen") == 2 * 72
    assert not cars.half_turn and proto.splits[1].half_turn
    names = [r.name for r in proto.rows]
    assert names[-3:] == ["refined with instance model (paper: near the category's mode)",
                          "refined with instance model + instance search",
                          "refined with instance model + instance search + morphing"]
    assert proto.preset == "default" and proto.main_row == names[-2]
    assert proto.rows[-1].params is not None and proto.rows[-1].params["morph_views"]
    assert proto.rows[-3].params["recognition"].search is False


def test_coil_loio_leaves_each_instance_out_once(coil_dir):
    proto = load_protocol("coil-loio", coil_dir.parent)
    assert len(proto.splits) == 16
    left_out = [s.test.instances[0] for s in proto.splits]
    assert len(set(left_out)) == 16
    for s in proto.splits:
        assert len(set(s.test.instances)) == 1 and len(s.test.images) == 72
        assert s.test.instances[0] not in s.train.instances
        assert len(s.train.images) % 18 == 0
    half = {s.name.split("-")[0]: s.half_turn for s in proto.splits}
    assert half == {"cars": False, "boxes": True, "bottles": True}
    assert proto.main_row in {r.name for r in proto.rows}


def test_epfl_protocols(epfl_dir):
    single = load_protocol("epfl-single", epfl_dir.parent.parent)
    assert [len(s.train.images) for s in single.splits] == [15, 30, 40]
    for s in single.splits:
        assert len(s.train.images) + len(s.test.images) == 118
        assert not set(s.train.images) & set(s.test.images)
    cv = load_protocol("epfl-cv", epfl_dir)
    assert len(cv.splits) == 5
    tested = [sorted(set(s.test.instances)) for s in cv.splits]
    assert tested[0] == ["car01", "car02"] and tested[-1] == ["car09", "car10"]
    for s in cv.splits:
        # eight cars train, the other two test: every car is tested once, never on its own model
        assert len(set(s.train.instances)) == 8
        assert not set(s.train.instances) & set(s.test.instances)
    assert sorted(n for t in tested for n in t) == [f"car{c:02d}" for c in range(1, 11)]
    a, b = epfl_cv(epfl_dir, folds=2).splits
    assert set(a.test.instances) == set(b.train.instances) == {f"car{c:02d}" for c in range(1, 6)}
    for bad in (1, 11, 2.5):
        with pytest.raises(ValueError, match="folds"):
            epfl_cv(epfl_dir, folds=bad)
    # cars 11-20 are held out: their images are not in ../shared
    with pytest.raises(FileNotFoundError, match="EPFL image not found"):
        load_protocol("epfl-10-10", epfl_dir)
    assert set(PROTOCOLS) == {"coil-category", "coil-loio", "epfl-single", "epfl-10-10",
                              "epfl-cv"}


def test_epfl_single_on_development_cars(epfl_dir):
    # The protocol of Fig. 6 on other cars (the development set of its settings).
    dev = epfl_single(epfl_dir, cars=(2, 3))
    assert [s.name for s in dev.splits] == ["car02-15", "car02-30", "car02-40",
                                           "car03-15", "car03-30", "car03-40"]
    assert {n for s in dev.splits for n in s.train.instances + s.test.instances} == {
        "car02", "car03"}
    assert dev.preset == load_protocol("epfl-single", epfl_dir).preset == "turntable"
    assert dev.rows == load_protocol("epfl-single", epfl_dir).rows
    assert "cars 2, 3" in dev.description
    with pytest.raises(ValueError, match="at least one car"):
        epfl_single(epfl_dir, cars=())


def test_epfl_10_10_default_rows_exist():
    # The protocol needs cars 11-20 to be built; its default rows must name real rows.
    from posevote.evaluation.protocols import _EPFL_10_10_DEFAULT_ROWS, _EPFL_ROWS

    assert set(_EPFL_10_10_DEFAULT_ROWS) <= {r.name for r in _EPFL_ROWS}
    assert _EPFL_10_10_DEFAULT_ROWS[0] == _EPFL_ROWS[1].name


def test_every_row_builds_an_estimator_from_its_protocols_preset(coil_dir, epfl_dir):
    from posevote import PoseEstimator

    for name in ("coil-category", "coil-loio", "epfl-single", "epfl-cv"):
        proto = load_protocol(name, coil_dir.parent)
        assert proto.main_row in {r.name for r in proto.rows}
        # --rows takes a comma-separated list: a row's name has no comma
        assert not [r.name for r in proto.rows if "," in r.name]
        for row in proto.rows:
            est = PoseEstimator.from_preset(proto.preset, **row.params)
            assert est.get_params(deep=False).keys() == PoseEstimator().get_params(deep=False).keys()
    # The paper's EPFL row runs edges alone; the preset's row adds the appearance stages.
    cv = load_protocol("epfl-cv", coil_dir.parent)
    paper, preset = (PoseEstimator.from_preset(cv.preset, **r.params) for r in cv.rows[:2])
    assert paper.appearance is None and preset.appearance is not None
    assert cv.rows[0].name.startswith("paper:")
