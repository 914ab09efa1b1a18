"""The appearance model: background boxes, objectness, jittered boxes and box regressions."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from posevote.appearance import AppearanceOptions
from posevote.appearance.descriptors import box_descriptor
from posevote.appearance.model import (
    AppearanceCollector,
    background_boxes,
    box_offsets,
    jittered_boxes,
    shift_box,
    train_box_regression,
    train_objectness,
)
from posevote.appearance.verify import regress_box, regress_described
from posevote.features.hog import descriptor_length
from posevote.geometry import box_iou


def test_background_boxes_miss_the_object_and_repeat_with_the_seed():
    box = (100.0, 60.0, 120.0, 60.0)
    a = background_boxes((250, 376), box, np.random.default_rng(3), attempts=50)
    b = background_boxes((250, 376), box, np.random.default_rng(3), attempts=50)
    assert a == b and len(a) > 10
    for x, y, w, h in a:
        iw = max(0.0, min(x + w, 220.0) - max(x, 100.0))
        ih = max(0.0, min(y + h, 120.0) - max(y, 60.0))
        assert iw * ih / (w * h + 120.0 * 60.0 - iw * ih) < 0.4


def test_objectness_separates_object_from_background():
    rng = np.random.default_rng(0)
    pos = rng.normal(1.0, 0.3, (30, 8)).astype(np.float32)
    neg = rng.normal(-1.0, 0.3, (60, 8)).astype(np.float32)
    w = train_objectness(pos, neg)
    assert w is not None and w.shape == (9,)
    assert np.all(pos @ w[:-1] + w[-1] > 0) and np.all(neg @ w[:-1] + w[-1] < 0)
    assert train_objectness(pos, neg[:5]) is None



_BOX = st.tuples(st.floats(-50, 200), st.floats(-50, 200), st.floats(5, 300), st.floats(5, 300))


@given(_BOX, _BOX)
def test_box_offsets_lead_to_the_target(box, target):
    np.testing.assert_allclose(shift_box(box, box_offsets(box, target)), target, atol=1e-6)
    np.testing.assert_allclose(box_offsets(target, target), 0.0, atol=1e-12)


def test_jittered_boxes_stay_near_and_repeat():
    box = (40.0, 30.0, 100.0, 50.0)
    a = jittered_boxes(box, np.random.default_rng(3), n=50)
    b = jittered_boxes(box, np.random.default_rng(3), n=50)
    assert a == b and len(a) == 50
    d = np.array([box_offsets(box, j) for j in a])
    assert np.all(np.abs(d[:, :2]) <= 0.15 * np.exp(0.15) + 1e-9)
    assert np.all(np.abs(d[:, 2:]) <= 0.15 * 1.5 + 1e-9)
    assert np.ptp(d, axis=0).min() > 0.05


def test_box_regression_moves_a_misplaced_box_onto_the_object(placed):
    rng = np.random.default_rng(0)
    window = (48, 48)
    az = np.radians(np.arange(0.0, 360.0, 5.0))
    descriptors, offsets, azimuths = [], [], []
    for a in az:
        img, box = placed(a)
        for b in jittered_boxes(box, rng, n=12):
            descriptors.append(box_descriptor(img, b, window))
            offsets.append(box_offsets(b, box))
            azimuths.append(a)
    regressor = train_box_regression(np.array(descriptors), np.array(offsets), np.array(azimuths),
                                     bins=4, alpha=10.0)
    assert regressor.shape == (4, 4, descriptor_length(window) + 1)
    before, after = [], []
    for a in np.radians([25.0, 95.0, 205.0, 310.0]):
        img, truth = placed(a, centre=(100.0, 100.0))
        x, y, w, h = truth
        off = (x + 0.15 * w, y - 0.12 * h, 0.85 * w, 1.12 * h)
        before.append(box_iou(off, truth))
        after.append(box_iou(regress_box(img, off, regressor, a, window=window), truth))
    # Every box ends nearer the object (IoU 0.77 before; 0.82-0.96 after over seeds 0-3).
    assert np.mean(after) > np.mean(before) + 0.08 and min(after) > max(before)
    # A box outside the image has no descriptor and stays where it is.
    far = (500.0, 500.0, 30.0, 30.0)
    assert regress_box(np.zeros((50, 50)), far, regressor, 0.0, window=window) == far
    # From a known descriptor: the same box, and the moved box's descriptor with it.
    moved, d = regress_described(img, off, box_descriptor(img, off, window), regressor, a,
                                 window=window)
    assert moved == regress_box(img, off, regressor, a, window=window)
    np.testing.assert_array_equal(d, box_descriptor(img, moved, window))
    assert regress_described(img, off, None, regressor, a, window=window) == (off, None)


def test_appearance_options_validate_themselves():
    import pytest

    with pytest.raises(ValueError, match=r"AppearanceOptions.jitter must be .* \[0, 0.5\)"):
        AppearanceOptions(jitter=0.7)
    with pytest.raises(ValueError, match="AppearanceOptions.candidates"):
        AppearanceOptions(candidates=-1)
    assert repr(AppearanceOptions(jitter=0.03)) == "AppearanceOptions(jitter=0.03)"


def test_collector_learns_descriptors_classifier_and_regression(placed):
    az = np.radians(np.arange(0.0, 360.0, 20.0))
    scenes = [placed(a) for a in az]
    boxes = np.array([b for _, b in scenes])
    collector = AppearanceCollector(boxes)
    for (img, box), a in zip(scenes, az, strict=True):
        collector.describe(img, box, float(a))
    model = collector.finish(boxes[:, 2:])
    assert model.descriptors.shape == (len(az), descriptor_length(model.window))
    assert model.objectness is not None and model.objectness.shape == (model.descriptors.shape[1] + 1,)
    assert model.regressor is not None and model.regressor.shape[1:] == (4, model.descriptors.shape[1] + 1)
