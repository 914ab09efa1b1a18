from dataclasses import replace

import cv2
import numpy as np
import pytest

from posevote import PoseEstimator
from posevote.geometry import angular_error
from posevote.keypoints.refine import keypoint_locate, keypoint_refine, share_between


def test_share_between_reads_how_far_the_keypoints_moved():
    rng = np.random.default_rng(0)
    start = rng.uniform(-40, 40, (30, 2))
    # Parallax: each keypoint moves its own way (the nearer, the farther).
    end = start + np.column_stack([rng.uniform(2, 12, 30), rng.normal(0, 1, 30)])
    for t in (0.0, 0.3, 0.75, 1.0):
        test = 1.1 * ((1 - t) * start + t * end) + (5.0, -3.0) + rng.normal(0, 0.2, (30, 2))
        assert share_between(test, start, end) == pytest.approx(t, abs=0.05)
    # A few wrong matches are dropped.
    test = (0.6 * start + 0.4 * end) + (2.0, 2.0)
    test[:3] += 30.0
    assert share_between(test, start, end) == pytest.approx(0.4, abs=0.05)


def test_share_between_needs_a_motion_that_differs_between_keypoints():
    start = np.random.default_rng(1).uniform(-40, 40, (10, 2))
    assert share_between(start + 1.0, start, start + 4.0) is None      # one shift for all
    assert share_between(3.0 * start, start, start + np.arange(20.0).reshape(10, 2)) is None


@pytest.fixture(scope="module")
def turning(cylinder):
    """The cylinder's model from views every 20 degrees, with the keypoint step."""
    azimuths = np.radians(np.arange(0, 360, 20))
    views = [cylinder(a) for a in azimuths]
    return PoseEstimator.from_preset("default", min_score=0.0, refine__keypoints=True).fit(
        [v[0] for v in views], np.column_stack([azimuths, np.zeros((18, 2))]),
        boxes=[v[1] for v in views])


def test_the_step_reads_the_viewpoint_between_the_views(turning, cylinder):
    errors, without = [], []
    for azimuth in np.radians([5.0, 10.0, 47.0, 133.0, 250.0, 318.0]):
        image, _ = cylinder(azimuth)
        errors.append(angular_error(turning.estimate(image).best.azimuth, azimuth))
        off = turning.set_params(refine__keypoints=False).estimate(image).best.azimuth
        without.append(angular_error(off, azimuth))
        turning.set_params(refine__keypoints=True)
    assert np.degrees(np.max(errors)) < 2.5
    assert np.mean(errors) < np.mean(without)


def test_a_half_turned_pose_turns_back_to_its_printed_side(turning, cylinder):
    image, _ = cylinder(np.radians(70.0))
    found = turning.estimate(image).best
    flipped = replace(found, azimuth=float(np.mod(found.azimuth + np.pi, 2 * np.pi)))
    back, share = keypoint_refine(flipped, turning.full_model_, image)
    assert np.degrees(angular_error(back.azimuth, np.radians(70.0))) < 2.5
    assert share is not None and 0.6 <= share <= 1    # 1.5 times the near views' inliers at least
    # The found pose stays where it is, and the score and the box with it.
    same, share = keypoint_refine(found, turning.full_model_, image)
    assert share is None and (same.score, same.box) == (found.score, found.box)


def test_a_far_view_with_half_again_the_near_views_inliers_turns_the_pose(turning, cylinder,
                                                                          monkeypatch):
    import posevote.keypoints.refine as refine

    image, _ = cylinder(np.radians(70.0))
    found = turning.estimate(image).best
    flipped = replace(found, azimuth=float(np.mod(found.azimuth + np.pi, 2 * np.pi)))
    model = turning.full_model_
    far = int(np.argmin(angular_error(model.view_azimuth, np.radians(60.0))))
    near = int(np.argmin(angular_error(model.view_azimuth, flipped.azimuth)))

    def counted(xy, desc, model, views):
        # 15 inliers on the far side, 10 near the estimate: 1.5 times, not twice.
        sizes = {far: 15, near: 10}
        return [np.column_stack([np.arange(sizes.get(int(v), 0)),
                                 np.flatnonzero(model.keypoint_view == v)[:sizes.get(int(v), 0)]])
                for v in views]

    monkeypatch.setattr(refine, "view_inliers", counted)
    back, share = keypoint_refine(flipped, model, image)
    assert np.degrees(angular_error(back.azimuth, np.radians(60.0))) < 1e-6
    assert share == pytest.approx(15 / 25)


def test_nothing_to_match_leaves_the_pose(turning):
    blank = np.zeros((128, 128))
    found = turning.full_model_
    pose = turning.set_params(refine__keypoints=False).estimate(np.pad(
        np.eye(64), 32)).best
    turning.set_params(refine__keypoints=True)
    assert keypoint_refine(pose, found, blank) == (pose, None)


def test_a_model_without_keypoints_is_refused(turning, cylinder):
    plain = PoseEstimator.from_preset("default", refine__keypoints=False).fit(
        [cylinder(0.0)[0]], np.zeros((1, 3)), boxes=[cylinder(0.0)[1]])
    image, _ = cylinder(0.0)
    pose = plain.estimate(image).best or turning.estimate(image).best
    with pytest.raises(ValueError, match="refine=RefineOptions\\(keypoints=True\\)"):
        keypoint_refine(pose, plain.full_model_, image)


def test_the_same_image_gives_the_same_pose(turning, cylinder):
    image, _ = cylinder(np.radians(123.0))
    found = turning.set_params(refine__keypoints=False).estimate(image).best
    turning.set_params(refine__keypoints=True)
    first = keypoint_refine(found, turning.full_model_, image)
    keypoint_refine(found, turning.full_model_, cylinder(np.radians(10.0))[0])  # RANSAC between
    assert keypoint_refine(found, turning.full_model_, image) == first


def test_an_upright_search_reads_between_views_whatever_turn_the_mode_got(turning, cylinder):
    image, _ = cylinder(np.radians(50.0))
    found = turning.set_params(refine__keypoints=False).estimate(image).best
    turning.set_params(refine__keypoints=True)
    tilted = replace(found, inplane=np.radians(4.0))         # a refinement's own turn
    level, _ = keypoint_refine(replace(found, inplane=0.0), turning.full_model_, image)
    kept, _ = keypoint_refine(tilted, turning.full_model_, image, upright=True)
    assert kept.azimuth == level.azimuth and kept.inplane == tilted.inplane


def test_the_texture_locates_the_object_where_the_mode_missed_it(turning, cylinder):
    view, box = cylinder(np.radians(70.0))
    # The object at 1.3 times its size, turned 10 degrees, in the corner of a larger frame.
    turn = cv2.getRotationMatrix2D((64.0, 64.0), -10.0, 1.3)
    turn[:, 2] += (200.0, 150.0)
    frame = cv2.warpAffine(view.astype(np.float32), turn, (400, 320)).astype(np.float64)
    centre = turn[:, :2] @ (box[:2] + box[2:] / 2) + turn[:, 2]
    pose = turning.set_params(refine__keypoints=False).estimate(view).best
    turning.set_params(refine__keypoints=True)
    away = replace(pose, position=(40.0, 40.0), box=(10.0, 10.0, 60.0, 60.0))
    found = keypoint_locate(away, turning.full_model_, frame)
    assert found is not None
    located, share = found
    assert 0.5 < share <= 1.0          # the far side's views hold few of the inliers
    assert np.degrees(angular_error(located.azimuth, np.radians(70.0))) <= 20.0
    assert located.scale == pytest.approx(1.3 * pose.scale, rel=0.1)
    assert np.degrees(located.inplane) == pytest.approx(10.0, abs=3.0)
    # The nearest view is 10 degrees off: its reference point, a few pixels.
    assert np.hypot(*(np.array(located.position) - centre)) < 12.0
    # On the object already, the mode stays; a plain frame locates nothing.
    assert keypoint_locate(replace(away, box=located.box, position=located.position),
                           turning.full_model_, frame) is None
    assert keypoint_locate(away, turning.full_model_, np.zeros((320, 400))) is None


def test_a_reading_along_the_ring_keeps_the_fits_elevation(turning, cylinder):
    image, _ = cylinder(np.radians(47.0))
    found = turning.set_params(refine__keypoints=False).estimate(image).best
    turning.set_params(refine__keypoints=True)
    raised = replace(found, elevation=0.1)
    read, share = keypoint_refine(raised, turning.full_model_, image)
    assert share is None and read.azimuth != raised.azimuth    # read between the views
    assert read.elevation == 0.1                               # not snapped to the ring's 0


def test_clutter_matched_onto_a_few_keypoints_places_nothing(turning, cylinder, monkeypatch):
    # Three test keypoints a few pixels apart, each the centre of a third of the views'
    # descriptors, and keypoints that match nothing (a descriptor far from every view's).
    model = turning.full_model_
    criteria = (cv2.TERM_CRITERIA_MAX_ITER, 20, 0.0)
    _, _, centres = cv2.kmeans(model.keypoint_descriptor.astype(np.float32), 3, None,
                               criteria, 1, cv2.KMEANS_PP_CENTERS)
    far = np.column_stack([np.arange(20.0, 380.0, 60.0), np.full(6, 300.0)])
    keypoints = (np.vstack([[[100.0, 100.0], [103.0, 100.0], [100.0, 103.0]], far]),
                 np.vstack([np.clip(np.round(centres), 0, 255),
                            np.full((6, 128), 255.0)]).astype(np.uint8))
    fit = cv2.estimateAffinePartial2D

    def shrunk(view_xy, test_xy, **kw):
        # RANSAC shrinks a view onto one of the three points, holding a third of its
        # matches; on a real frame its scale came out 3e-20, not 0.
        fitted, inlier = fit(view_xy, test_xy, **kw)
        if fitted is not None and np.hypot(*fitted[:, 0]) < 1e-6:
            fitted = np.column_stack([1e-20 * np.eye(2), fitted[:, 2]])
        return fitted, inlier

    monkeypatch.setattr("posevote.keypoints.refine.cv2.estimateAffinePartial2D", shrunk)
    view, _ = cylinder(np.radians(70.0))
    pose = turning.set_params(refine__keypoints=False).estimate(view).best
    turning.set_params(refine__keypoints=True)
    away = replace(pose, position=(40.0, 40.0), box=(10.0, 10.0, 60.0, 60.0))
    assert keypoint_locate(away, model, np.zeros((320, 400)), keypoints=keypoints) is None


def test_a_larger_frame_is_given_keypoints_by_its_area(turning, cylinder, monkeypatch):
    import posevote.keypoints.refine as refine

    asked = []

    def detect(image, mask=None, *, limit):
        asked.append(limit)
        return np.zeros((0, 2)), np.zeros((0, 128), dtype=np.uint8)

    monkeypatch.setattr(refine, "detect_keypoints", detect)
    view, _ = cylinder(np.radians(70.0))
    pose = turning.set_params(refine__keypoints=False).estimate(view).best
    turning.set_params(refine__keypoints=True)
    for shape in ((320, 400), (480, 640), (720, 1280)):
        assert keypoint_locate(pose, turning.full_model_, np.zeros(shape)) is None
    # A 640 x 480 frame's number at most, and as many per its area in a larger one.
    assert asked == [refine.LOCATE_KEYPOINTS] * 2 + [3 * refine.LOCATE_KEYPOINTS]
