import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from posevote.geometry import (
    angle_difference,
    angular_error,
    pose_from_rotation,
    rotate_points,
    rotation_from_pose,
    transform_from_pose,
    viewing_direction,
    wrap_angle,
)

angles = st.floats(-20.0, 20.0, allow_nan=False)


@given(angles)
def test_wrap_angle_in_range(a):
    w = wrap_angle(a)
    assert 0.0 <= w < 2 * np.pi
    assert np.isclose(np.cos(w), np.cos(a)) and np.isclose(np.sin(w), np.sin(a))


@given(angles, angles)
def test_angular_error_symmetric_and_bounded(a, b):
    e = angular_error(a, b)
    assert np.isclose(e, angular_error(b, a))
    assert 0.0 <= e <= np.pi + 1e-12
    assert angular_error(a, a) == pytest.approx(0.0, abs=1e-12)


@given(angles, angles)
def test_half_turn_error_ignores_half_turns(a, b):
    assert angular_error(a + np.pi, b, period=np.pi) == pytest.approx(
        angular_error(a, b, period=np.pi), abs=1e-9)
    assert angular_error(a, b, period=np.pi) <= np.pi / 2 + 1e-12


def test_angle_difference_sign():
    assert angle_difference(np.radians(10), np.radians(350)) == pytest.approx(np.radians(20))
    assert angle_difference(np.radians(350), np.radians(10)) == pytest.approx(np.radians(-20))


@settings(max_examples=60)
@given(st.floats(0, 2 * np.pi - 1e-6), st.floats(-1.5, 1.5), st.floats(0, 2 * np.pi - 1e-6))
def test_rotation_orthonormal_and_round_trip(az, el, roll):
    R = rotation_from_pose(az, el, roll)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    az2, el2, roll2 = pose_from_rotation(R)
    assert np.allclose(rotation_from_pose(az2, el2, roll2), R, atol=1e-9)
    assert el2 == pytest.approx(el, abs=1e-9)


def test_zero_pose_faces_camera():
    R = rotation_from_pose(0.0, 0.0, 0.0)
    # object front (+x) points at the camera (-Z); object up (+z) is image up (-Y)
    assert np.allclose(R @ [1, 0, 0], [0, 0, -1])
    assert np.allclose(R @ [0, 0, 1], [0, -1, 0])


def test_viewing_direction_matches_rotation():
    for az in np.radians([0, 30, 120, 250]):
        R = rotation_from_pose(az, 0.3, 0.0)
        # the camera sits along -Z in camera coordinates, seen from the object
        to_camera_obj = R.T @ np.array([0.0, 0.0, -1.0])
        assert np.allclose(to_camera_obj, viewing_direction(az, 0.3), atol=1e-12)


def test_transform_from_pose_back_projects():
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    T = transform_from_pose(0.1, 0.0, 0.0, 2.0, 400.0, 200.0, K=K, reference_depth=4.0)
    p = K @ T[:3, 3]
    assert p[:2] / p[2] == pytest.approx([400.0, 200.0])
    assert T[2, 3] == pytest.approx(2.0)
    with pytest.raises(ValueError, match="scale must be positive"):
        transform_from_pose(0, 0, 0, 0.0, 1, 1, K=K, reference_depth=1)


def test_pose_from_rotation_rejects_bad_shape():
    with pytest.raises(ValueError, match=r"shape \(3, 3\)"):
        pose_from_rotation(np.eye(2))


def test_rotate_points_direction():
    # +90 degrees turns +u into +v (clockwise on screen, v down)
    assert np.allclose(rotate_points(np.array([[1.0, 0.0]]), np.pi / 2), [[0.0, 1.0]])


def test_box_iou_broadcasts():
    from posevote.geometry import box_iou

    boxes = np.array([[0, 0, 10, 10], [5, 0, 10, 10], [20, 20, 5, 5], [0, 0, 0, 0]], float)
    np.testing.assert_allclose(box_iou(boxes, [0, 0, 10, 10]), [1.0, 50 / 150, 0.0, 0.0])


def test_box_centre_is_the_middle_pixel():
    from posevote.geometry import box_centre

    assert box_centre((0, 0, 1, 1)) == (0.0, 0.0)
    assert box_centre(np.array([10.0, 20.0, 5.0, 4.0])) == (12.0, 21.5)


def test_rotation_angle_is_the_geodesic_between_rotations():
    from posevote.geometry import rotation_angle, rotation_from_pose

    a = rotation_from_pose(0.3, 0.2, 0.1)
    assert rotation_angle(a, a) == pytest.approx(0.0, abs=1e-6)
    assert rotation_angle(a, rotation_from_pose(0.3, 0.2, 0.8)) == pytest.approx(0.7, abs=1e-9)
    assert rotation_angle(a, rotation_from_pose(0.3 + np.pi, 0.2, 0.1)) > 2.0


def test_box_iou_of_one_pair_of_tuples_is_the_arrays_bit_for_bit():
    from posevote.geometry import box_iou

    rng = np.random.default_rng(5)
    for _ in range(200):
        a, b = tuple(rng.uniform(-20, 60, 4)), tuple(rng.uniform(-20, 60, 4))
        a, b = a[:2] + (abs(a[2]), abs(a[3])), b[:2] + (abs(b[2]), abs(b[3]))
        assert box_iou(a, b) == box_iou(np.array(a), np.array(b))
    assert box_iou((0, 0, 0, 0), (0, 0, 0, 0)) == 0.0
    # Not finite: the arrays' answer.
    assert box_iou((np.nan, 0, 1, 1), (0, 0, 1, 1)) == box_iou(np.array([np.nan, 0, 1, 1]),
                                                               np.array([0, 0, 1, 1]))
