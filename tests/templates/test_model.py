import cv2
import numpy as np
import pytest

from posevote.templates.model import TEMPLATE_SIDE, template_frame, view_template


def _pattern(size=128):
    rng = np.random.default_rng(3)
    noise = cv2.GaussianBlur(rng.random((size, size)).astype(np.float32), (0, 0), 3.0)
    return (noise - noise.min()) / np.ptp(noise)


def test_template_frame_puts_the_template_centre_on_the_centre():
    frame = template_frame(np.array([40.0, 30.0]), 2.0, np.radians(90))
    half = (TEMPLATE_SIDE - 1) / 2.0
    np.testing.assert_allclose(frame @ [half, half, 1.0], [40.0, 30.0])
    # One template pixel right is two image pixels down at 90 degrees.
    np.testing.assert_allclose(frame @ [half + 1, half, 1.0], [40.0, 32.0], atol=1e-12)


def test_template_is_the_box_nan_outside_the_mask():
    image = _pattern()
    box = np.array([30.0, 20.0, 40.0, 60.0])
    mask = np.zeros(image.shape, bool)
    mask[20:80, 30:50] = True                      # the left half of the box only
    template, cell = view_template(image, box, mask, 0.0)
    assert template.shape == (TEMPLATE_SIDE, TEMPLATE_SIDE) and template.dtype == np.float16
    assert cell == pytest.approx(np.hypot(40.0, 60.0) / TEMPLATE_SIDE)
    valid = np.isfinite(template)
    rows, cols = np.nonzero(valid)
    frame = template_frame(np.array([50.0, 50.0]), cell, 0.0)
    # The valid pixels land inside the mask, and cover most of it.
    xy = np.column_stack([cols, rows, np.ones(len(rows))]) @ frame.T
    assert np.all((xy[:, 0] >= 29.0) & (xy[:, 0] <= 50.0) & (xy[:, 1] >= 19.0) & (xy[:, 1] <= 80.0))
    assert valid.sum() * cell ** 2 > 0.8 * mask.sum()
    whole, _ = view_template(image, box, None, 0.0)
    assert np.isfinite(whole).sum() > 1.8 * valid.sum()


def test_template_undoes_the_views_inplane_angle():
    image = _pattern()
    box = np.array([24.0, 24.0, 80.0, 80.0])
    angle = np.radians(35)
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    centre = np.array([63.5, 63.5])
    turned = cv2.warpAffine(image, np.hstack([rot, (centre - rot @ centre)[:, None]]), (128, 128),
                            flags=cv2.INTER_LINEAR)
    upright, _ = view_template(image, box, None, 0.0)
    again, _ = view_template(turned, box, None, angle)
    both = np.isfinite(upright) & np.isfinite(again)
    # The inner disc (the turned box's corners hold the warp's black border).
    rows, cols = np.indices(upright.shape)
    half = (TEMPLATE_SIDE - 1) / 2.0
    both &= np.hypot(rows - half, cols - half) < 0.3 * TEMPLATE_SIDE
    a, b = upright[both].astype(float), again[both].astype(float)
    assert np.corrcoef(a, b)[0, 1] > 0.98


def test_training_keeps_each_views_template(synthetic_training):
    from posevote import PoseEstimator
    from posevote.templates import TemplateOptions

    images, az, boxes = synthetic_training
    model = PoseEstimator(templates=TemplateOptions()).fit(images, az, boxes=boxes).model_
    assert model.view_template.shape == (model.n_views, TEMPLATE_SIDE, TEMPLATE_SIDE)
    assert np.all(model.view_template_cell > 0)
    # The synthetic views all have the reference size: cells are the views' own.
    boxes = model.view_box
    np.testing.assert_allclose(model.view_template_cell, np.hypot(boxes[:, 0], boxes[:, 1])
                               / TEMPLATE_SIDE, rtol=1e-9)
