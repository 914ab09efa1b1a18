"""Appearance descriptors of boxes (HOG of the crop in a fixed window)."""

from __future__ import annotations

import numpy as np

from posevote.appearance.descriptors import box_descriptor, window_shape
from posevote.features.hog import descriptor_length


def test_window_follows_the_boxes_shape():
    assert window_shape(np.array([[200.0, 100.0], [180.0, 100.0], [220.0, 100.0]])) == (48, 96)
    assert window_shape(np.array([[10.0, 100.0]])) == (48, 24)
    assert window_shape(np.array([[1000.0, 10.0]])) == (48, 144)


def test_descriptor_of_a_crop_is_where_it_lies(draw):
    obj = draw(np.radians(30.0), size=96)
    big = np.zeros((200, 300))
    big[50:146, 120:216] = obj
    window = (48, 48)
    a = box_descriptor(obj, (0, 0, 96, 96), window)
    b = box_descriptor(big, (120, 50, 96, 96), window)
    assert a is not None and a.shape == (descriptor_length(window),)
    np.testing.assert_allclose(a, b, atol=1e-6)
    assert box_descriptor(big, (295, 10, 40, 40), window) is None
    assert box_descriptor(big, (-100, -100, 50, 50), window) is None


