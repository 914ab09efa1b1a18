"""Outlines: the support function of a mask's hull, and the box of a turned outline."""

import cv2
import numpy as np
import pytest

from posevote.model.outline import (
    OUTLINE_ANGLES,
    box_outline,
    inside_outline,
    mask_outline,
    outline_at,
    outline_box,
)
from posevote.refinement.fitting import box_from_pose


def test_a_boxes_outline_gives_the_turned_box_at_the_sampled_angles():
    outline = box_outline(np.array([40.0, 90.0]))
    assert outline.shape == (OUTLINE_ANGLES,)
    for deg in (0, 10, -30, 90, 170):
        alpha = np.radians(deg)
        np.testing.assert_allclose(outline_box(outline, (100.0, 50.0), 1.2, alpha),
                                   box_from_pose(np.array([100.0, 50.0]),
                                                 np.array([40.0, 90.0]) * 1.2, alpha), atol=1e-9)
    # Between the samples the interpolation reads slightly inside the box, never outside.
    x, y, w, h = outline_box(outline, (0.0, 0.0), 1.0, np.radians(25))
    *_, bw, bh = box_from_pose(np.zeros(2), np.array([40.0, 90.0]), np.radians(25))
    assert bw * 0.99 < w <= bw and bh * 0.99 < h <= bh


def test_a_rectangular_masks_outline_is_its_boxes():
    mask = np.zeros((60, 80), bool)
    mask[10:30, 5:45] = True                            # the box (5, 10, 40, 20)
    np.testing.assert_allclose(mask_outline(mask, np.array([25.0, 20.0]), 0.0),
                               box_outline(np.array([40.0, 20.0])), atol=1e-9)
    with pytest.raises(ValueError, match="at least one pixel"):
        mask_outline(np.zeros((5, 5), bool), np.zeros(2), 0.0)


def test_a_turned_masks_box_is_read_from_its_upright_outline():
    # A triangle, upright in training, then turned by 30° about its box centre.
    mask = np.zeros((200, 200), np.uint8)
    cv2.fillPoly(mask, [np.array([[60, 60], [140, 60], [60, 140]], np.int32)], 1)
    centre = np.array([100.5, 100.5])
    outline = mask_outline(mask.astype(bool), centre, 0.0)
    turn = cv2.getRotationMatrix2D((float(centre[0]), float(centre[1])), -30.0, 1.0)
    turned = cv2.warpAffine(mask, turn, (200, 200), flags=cv2.INTER_NEAREST).astype(bool)
    rows, cols = np.nonzero(turned)
    truth = (cols.min(), rows.min(), np.ptp(cols) + 1, np.ptp(rows) + 1)
    np.testing.assert_allclose(outline_box(outline, tuple(centre), 1.0, np.radians(30)), truth,
                               atol=2.0)
    # The view turned in training reads the same outline once its angle is undone.
    np.testing.assert_allclose(mask_outline(turned, centre, np.radians(30)), outline, atol=1.5)


def test_outline_at_averages_the_views_near_a_viewpoint(toy_model):
    from dataclasses import replace

    model = toy_model()
    assert outline_at(model, 0.0, 0.0, kappa=10.0, k1_cutoff=0.1) is None
    outlines = np.array([box_outline(np.array([10.0 + k, 20.0])) for k in range(model.n_views)])
    model = replace(model, view_outline=outlines)
    nearest = int(np.argmin(np.abs(np.angle(np.exp(1j * (model.view_azimuth - 0.3))))))
    sharp = outline_at(model, float(model.view_azimuth[nearest]),
                       float(model.view_elevation[nearest]), kappa=1e4, k1_cutoff=0.1)
    np.testing.assert_allclose(sharp, outlines[nearest], atol=1e-6)


def test_inside_outline_follows_the_turned_and_scaled_mask():
    mask = np.zeros((80, 80), bool)
    mask[20:40, 10:70] = True  # 60 wide, 20 tall, reference point at its centre
    outline = mask_outline(mask, (40.0, 30.0), 0.0)
    alpha, scale, position = np.radians(90.0), 0.5, np.array([100.0, 50.0])
    # Turned a quarter, halved: 10 wide and 30 tall around (100, 50).
    inside = inside_outline([[100.0, 50.0], [100.0, 63.0], [103.0, 50.0], [100.0, 68.0],
                             [108.0, 50.0]], outline, position, scale, alpha)
    assert inside.tolist() == [True, True, True, False, False]
    # Every mask pixel lies inside its own outline, and no point beyond its box does.
    rows, cols = np.nonzero(mask)
    assert inside_outline(np.column_stack([cols, rows]), outline, (40.0, 30.0), 1.0, 0.0).all()
    assert not inside_outline([[75.0, 30.0], [40.0, 45.0]], outline, (40.0, 30.0), 1.0, 0.0).any()
