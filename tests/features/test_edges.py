import cv2
import numpy as np
import pytest

from posevote.features import box_mask, detect_edges, normalize_features
from posevote.features.edges import EdgeOptions, extract_edges, frame_budget


def square(size=64, lo=16, hi=48):
    img = np.zeros((size, size))
    img[lo:hi, lo:hi] = 1.0
    return img


def test_edges_lie_on_the_square_with_tangent_orientation():
    f = detect_edges(square(), spacing=1.0)
    assert len(f) > 60
    near_vertical_side = np.abs(f.xy[:, 0] - 16) <= 1.5
    near_horizontal_side = np.abs(f.xy[:, 1] - 16) <= 1.5
    mid = (f.xy[:, 1] > 22) & (f.xy[:, 1] < 42)
    # vertical sides have tangents near pi/2, horizontal ones near 0 (mod pi)
    assert np.all(np.abs(f.theta[near_vertical_side & mid] - np.pi / 2) < 0.1)
    mid_h = (f.xy[:, 0] > 22) & (f.xy[:, 0] < 42)
    th = f.theta[near_horizontal_side & mid_h]
    assert np.all(np.minimum(th, np.pi - th) < 0.1)
    assert np.all((f.theta >= 0) & (f.theta < np.pi))


def test_budget_and_even_spacing():
    many = detect_edges(square(128, 10, 118), spacing=1.0)
    few = detect_edges(square(128, 10, 118), spacing=1.0, max_points=50)
    assert len(few) <= 50 < len(many)
    # evenly spread: the points still cover all four sides
    assert few.xy[:, 0].min() < 14 and few.xy[:, 0].max() > 114
    assert few.xy[:, 1].min() < 14 and few.xy[:, 1].max() > 114


def test_mask_restricts_and_blank_image_is_empty():
    img = square()
    mask = box_mask(img.shape, np.array([0.0, 0.0, 32.0, 64.0]))
    f = detect_edges(img, mask=mask)
    assert f.xy[:, 0].max() <= 33
    assert len(detect_edges(np.zeros((32, 32)))) == 0


def test_bad_arguments():
    with pytest.raises(ValueError, match="thresholds"):
        detect_edges(square(), low_threshold=0.2, high_threshold=0.1)
    with pytest.raises(ValueError, match="mask has shape"):
        detect_edges(square(), mask=np.ones((3, 3), bool))


def test_normalize_features_round_trip():
    f = detect_edges(square())
    n = normalize_features(f, center=np.array([31.5, 31.5]), scale=2.0, inplane=0.3)
    assert np.abs(n.xy).max() < 10
    assert np.all((n.theta >= 0) & (n.theta < np.pi))


def test_a_mask_keeps_the_whole_images_edges_inside_it():
    # Textured, so that edges run across the mask's border; one point per pixel.
    rng = np.random.default_rng(3)
    img = np.clip(square(96, 20, 70) * 0.6 + rng.random((96, 96)) * 0.4, 0, 1)
    whole = detect_edges(img, spacing=0.5)
    mask = box_mask(img.shape, np.array([30.0, 25.0, 40.0, 50.0]))
    part = detect_edges(img, spacing=0.5, mask=mask)
    inside = mask[whole.xy[:, 1].astype(int), whole.xy[:, 0].astype(int)]
    assert 0 < len(part) < len(whole)
    np.testing.assert_array_equal(part.xy, whole.xy[inside])
    # The orientations, smoothed only around the kept points, are the whole image's.
    np.testing.assert_array_equal(part.theta, whole.theta[inside])
    assert len(detect_edges(img, mask=np.zeros(img.shape, bool))) == 0


def test_a_larger_test_frame_keeps_the_spacing_of_a_640_by_480_one():
    options = EdgeOptions(max_test_features=100)
    assert frame_budget(options, (480, 640)) == 100
    assert frame_budget(options, (250, 376)) == 100      # never fewer than the budget
    assert frame_budget(options, (720, 1280)) == 300
    assert frame_budget(EdgeOptions(max_test_features=None), (720, 1280)) is None
    # The same texture at both sizes: the points are as dense in the larger frame.
    rng = np.random.default_rng(0)
    texture = cv2.resize(rng.random((60, 80)), (1280, 960), interpolation=cv2.INTER_NEAREST)
    small = extract_edges(texture[:480, :640], options, training=False)
    large = extract_edges(texture, options, training=False)
    assert 90 <= len(small) <= 100 and 360 <= len(large) <= 400
    assert len(extract_edges(texture, options, training=True)) <= 300
