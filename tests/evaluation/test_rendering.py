import numpy as np
import pytest

from posevote.evaluation.rendering import RENDER_FOV_DEG, render_focal, render_turntable

pytest.importorskip("pybullet")


def test_render_turntable_frames_any_mesh():
    views = render_turntable(np.radians([0.0, 90.0, 200.0]), size=64, mesh="racecar/racecar.urdf",
                             base_euler=(0.0, 0.0, 0.0), distance=None)
    for view in views:
        assert view.mask.any()
        x, y, w, h = view.box
        assert x > 0 and y > 0 and x + w < 64 and y + h < 64  # whole object in view
        assert abs(x + w / 2 - 32) < 8  # turns about its own centre
    assert not np.array_equal(views[0].mask, views[1].mask)


def test_a_texture_is_laid_over_the_mesh():
    plain, = render_turntable(np.radians([30.0]), size=64, distance=None)
    laid, = render_turntable(np.radians([30.0]), size=64, distance=None, texture="uvmap.png")
    np.testing.assert_array_equal(plain.mask, laid.mask)
    # The yellow duck is nearly one grey; the test image's squares and letters are not.
    assert laid.image[laid.mask].std() > 2 * plain.image[plain.mask].std()
    with pytest.raises(FileNotFoundError, match="'nothing.png': no such image"):
        render_turntable(np.radians([0.0]), size=32, texture="nothing.png")


def test_render_turntable_says_when_the_object_is_out_of_view():
    with pytest.raises(ValueError, match="duck_vhacd.urdf: the object is not in view"):
        render_turntable(np.radians([0.0]), size=32, target=(5.0, 5.0, 5.0))


def test_render_focal_is_the_field_of_view_at_the_image_size():
    f = render_focal(128)
    assert 2 * np.degrees(np.arctan(64 / f)) == pytest.approx(RENDER_FOV_DEG)
    assert render_focal(256) == pytest.approx(2 * f)


def test_the_mesh_origin_is_given_in_the_camera_frame():
    import pybullet

    from posevote.evaluation.rendering import camera_point

    # The camera's target lies straight ahead at its distance; up in the world is up
    # in the image (OpenCV's y down).
    view = pybullet.computeViewMatrixFromYawPitchRoll(
        cameraTargetPosition=[0.1, 0.2, 0.3], distance=2.0, yaw=0.0, pitch=-30.0, roll=0.0,
        upAxisIndex=2)
    np.testing.assert_allclose(camera_point(view, np.array([0.1, 0.2, 0.3])), [0, 0, 2],
                               atol=1e-6)
    assert camera_point(view, np.array([0.1, 0.2, 0.4]))[1] < 0
    # The duck's origin, turned with it about its box's centre, projects onto the duck
    # and moves as it turns.
    views = render_turntable(np.radians([0.0, 90.0, 200.0]), size=64, distance=None)
    f = render_focal(64)
    for v in views:
        u, w = f * v.origin[:2] / v.origin[2] + 31.5
        assert v.mask[int(round(w)), int(round(u))]
    assert np.ptp([v.origin for v in views], axis=0).max() > 1e-3


def test_a_posed_render_puts_the_object_where_the_pinhole_does():
    from posevote.evaluation.rendering import mesh_size, render_posed
    from posevote.geometry import rotation_from_pose

    extent = mesh_size()
    # From straight above, 0.5 m up: the footprint is centred on the principal point and
    # as wide as the mesh at that depth.
    R = rotation_from_pose(0.0, np.radians(89.9), 0.0)
    t = np.array([0.0, 0.0, 0.5])
    (rgb, mask), = render_posed([(R, t)], intrinsics=(600.0, 600.0, 320.0, 240.0),
                                size=(640, 480))
    rows, cols = np.nonzero(mask)
    assert rgb.shape == (480, 640, 3) and rgb.dtype == np.uint8
    assert abs((cols.min() + cols.max()) / 2 - 320) <= 2
    assert abs((rows.min() + rows.max()) / 2 - 240) <= 2
    near = 0.5 - extent[2]      # the top is nearer than the base: the widest it can look
    assert 600 * extent[1] / 0.5 - 3 <= np.ptp(cols) + 1 <= 600 * extent[1] / near + 3
    # From the side at the object's base height: it stands on the horizon row.
    R = rotation_from_pose(0.0, 0.0, 0.0)
    (_, mask), = render_posed([(R, t)], intrinsics=(600.0, 600.0, 320.0, 240.0),
                              size=(640, 480))
    assert abs(np.nonzero(mask)[0].max() - 240) <= 1
