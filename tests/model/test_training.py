"""Training: inputs checked and named, masks and instances, the appearance model."""

from __future__ import annotations

import numpy as np
import pytest

from posevote.model.pruning import PRESETS
from posevote.model.training import train_model


def test_bad_training_input(synthetic_training):
    images, az, _ = synthetic_training
    with pytest.raises(ValueError, match="at least one"):
        train_model([], [])
    with pytest.raises(ValueError, match="poses must have shape"):
        train_model(images[:2], az[:3])
    with pytest.raises(ValueError, match="row 1 is not finite"):
        train_model(images[:2], [0.0, np.nan])
    with pytest.raises(ValueError, match=r"images\[0\]: box .* is not inside"):
        train_model(images[:1], az[:1], boxes=[[100, 100, 50, 50]])
    with pytest.raises(ValueError, match=r"images\[0\]: no edges found"):
        train_model([np.zeros((32, 32))], [0.0])
    with pytest.raises(ValueError, match=r"boxes must have shape \(2, 4\)"):
        train_model(images[:2], az[:2], boxes=[[0, 0, 5, 5]])
    with pytest.raises(ValueError, match="mask shape"):
        train_model(images[:1], az[:1], masks=[np.ones((3, 3), bool)])
    with pytest.raises(ValueError, match="the mask is empty"):
        train_model(images[:1], az[:1], masks=[np.zeros(images[0].shape, bool)])
    with pytest.raises(ValueError, match="instances must have 2 entries"):
        train_model(images[:2], az[:2], instances=["a"])


def test_masks_instances_and_pruning(synthetic_training):
    images, az, _ = synthetic_training
    masks = [im > 0.05 for im in images]
    trained = train_model(images, az, masks=masks, instances=["a"] * 9 + ["b"] * 9,
                          prune=PRESETS["moderate"])
    assert trained.model.instance_names == ("a", "b") and trained.model.n_views == 18
    assert trained.model.n_features < trained.full_model.n_features
    assert trained.pruning == {"pose_std_deg": 10.0, "appearance_std": 1.2}
    assert trained.appearance is None and trained.viewpoint_kappa > 0


def test_appearance_descriptors_from_boxes_or_masks_agree(synthetic_training):
    # With every box given, the descriptors are computed image by image; with
    # boxes from masks, after all of them are known: the same boxes give the
    # same descriptors, classifier and regressions.
    images, az, boxes = synthetic_training
    masks = []
    for x, y, w, h in boxes:
        m = np.zeros(images[0].shape, bool)
        m[int(y):int(y + h), int(x):int(x + w)] = True
        masks.append(m)
    mask_boxes = np.array([[np.nonzero(m)[1].min(), np.nonzero(m)[0].min(),
                            np.ptp(np.nonzero(m)[1]) + 1, np.ptp(np.nonzero(m)[0]) + 1]
                           for m in masks], dtype=float)
    a = train_model(images, az, boxes=mask_boxes, appearance=True).appearance
    b = train_model(images, az, masks=masks, appearance=True).appearance
    assert a is not None and b is not None and a.window == b.window
    np.testing.assert_array_equal(a.descriptors, b.descriptors)
    assert (a.objectness is None) == (b.objectness is None)
    if a.objectness is not None:
        np.testing.assert_allclose(a.objectness, b.objectness)
    np.testing.assert_allclose(a.regressor, b.regressor)
