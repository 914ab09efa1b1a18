"""Training: inputs checked and named, masks and instances, the appearance model."""

from __future__ import annotations

import numpy as np
import pytest

from posevote.appearance.model import AppearanceCollector
from posevote.model.pruning import PRESETS
from posevote.model.training import train_model
from posevote.templates import TemplateOptions


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


def test_masks_give_outlines_and_views_without_one_their_box(synthetic_training):
    from posevote.model.outline import box_outline

    images, az, boxes = synthetic_training
    assert train_model(images, az, boxes=boxes).model.view_outline is None
    masks = [im > 0.05 if i % 2 else None for i, im in enumerate(images)]
    model = train_model(images, az, boxes=boxes, masks=masks).full_model
    assert model.view_outline is not None and model.view_outline.shape == (18, 36)
    np.testing.assert_allclose(model.view_outline[0], box_outline(model.view_box[0]))
    # A mask's hull lies inside its box (to the pixel) and is narrower somewhere.
    box = box_outline(model.view_box[1])
    assert np.all(model.view_outline[1] <= box + 1.0) and np.any(model.view_outline[1] < box - 1)


def test_masks_instances_and_pruning(synthetic_training):
    images, az, _ = synthetic_training
    masks = [im > 0.05 for im in images]
    trained = train_model(images, az, masks=masks, instances=["a"] * 9 + ["b"] * 9,
                          prune=PRESETS["moderate"])
    assert trained.model.instance_names == ("a", "b") and trained.model.n_views == 18
    assert trained.model.n_features < trained.full_model.n_features
    assert trained.pruning == {"pose_std_deg": 10.0, "appearance_std": 1.2}
    assert trained.appearance is None and trained.viewpoint_kappa > 0


def test_threads_train_the_same_model(synthetic_training):
    images, az, boxes = synthetic_training
    instances = ["a"] * 9 + ["b"] * 9
    one = train_model(images, az, boxes=boxes, instances=instances, collect=[AppearanceCollector])
    two = train_model(images, az, boxes=boxes, instances=instances,
                      collect=[AppearanceCollector], n_threads=3)
    for a, b in ((one.model, two.model), (one.full_model, two.full_model)):
        np.testing.assert_array_equal(a.xy, b.xy)
        np.testing.assert_array_equal(a.weight, b.weight)
    assert one.appearance is not None and two.appearance is not None
    np.testing.assert_array_equal(one.appearance.descriptors, two.appearance.descriptors)
    np.testing.assert_array_equal(one.appearance.regressor, two.appearance.regressor)
    # The first bad image is named, as without threads.
    bad = list(images)
    bad[5] = np.zeros((32, 32))
    with pytest.raises(ValueError, match=r"images\[5\]: no edges found"):
        train_model(bad, az, n_threads=2)


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
    a = train_model(images, az, boxes=mask_boxes, collect=[AppearanceCollector]).appearance
    b = train_model(images, az, masks=masks, collect=[AppearanceCollector]).appearance
    assert a is not None and b is not None and a.window == b.window
    np.testing.assert_array_equal(a.descriptors, b.descriptors)
    assert (a.objectness is None) == (b.objectness is None)
    if a.objectness is not None:
        np.testing.assert_allclose(a.objectness, b.objectness)
    np.testing.assert_allclose(a.regressor, b.regressor)


def test_extending_a_model_equals_training_on_everything(synthetic_training, draw, tmp_path):
    from posevote import PoseEstimator

    images, az, boxes = synthetic_training
    names = ["a"] * 9 + ["b"] * 9
    scaled = [img if i < 9 else draw(az[i], scale=0.8) for i, img in enumerate(images)]
    from posevote.data import object_box

    boxes = np.array([object_box(img) for img in scaled])
    masks = [img > 0.05 for img in scaled]              # the outlines are carried too
    templates = TemplateOptions()                        # and the templates
    whole = PoseEstimator(prune="moderate", templates=templates).fit(
        scaled, az, boxes=boxes, masks=masks, instances=names)
    first = PoseEstimator(prune="moderate", templates=templates).fit(
        scaled[:9], az[:9], boxes=boxes[:9], masks=masks[:9], instances=names[:9])
    first.save(tmp_path / "a.npz")
    grown = PoseEstimator.load(tmp_path / "a.npz").partial_fit(
        scaled[9:], az[9:], boxes=boxes[9:], masks=masks[9:], instances=names[9:])
    for name in ("xy", "theta", "view", "weight", "view_azimuth", "view_box", "view_instance",
                 "view_template", "view_template_cell", "view_outline", "view_lookalike"):
        np.testing.assert_allclose(getattr(grown.full_model_, name),
                                   getattr(whole.full_model_, name), atol=1e-9, err_msg=name)
    assert grown.full_model_.instance_names == whole.full_model_.instance_names == ("a", "b")
    assert grown.model_.n_features == whole.model_.n_features      # pruned again
    assert grown.viewpoint_kappa_ == pytest.approx(whole.viewpoint_kappa_)
    test = draw(np.radians(130))
    a, b = grown.estimate(test), whole.estimate(test)
    assert a.best.azimuth == pytest.approx(b.best.azimuth, abs=1e-9)
    assert a.best.score == pytest.approx(b.best.score, abs=1e-9)


def test_origins_name_the_point_t_is_placed_at(synthetic_training, draw):
    from posevote import PoseEstimator
    from posevote.camera import Camera
    from posevote.geometry import box_centre

    images, az, boxes = synthetic_training
    # The origin 10 px right of each box centre, turned with the view's in-plane angle 0.
    origins = np.array([box_centre(b) for b in boxes]) + [10.0, 0.0]
    est = PoseEstimator().fit(images, az, boxes=boxes, origins=origins, object_height_m=0.1)
    np.testing.assert_allclose(est.model_.view_origin, [[10.0, 0.0]] * len(images), atol=1e-9)
    camera = Camera(fx=400.0, fy=400.0, cx=63.5, cy=63.5)
    turned = draw(np.radians(60), scale=1.1, inplane=np.radians(20))
    est.set_params(search__inplane_range_deg=(-30.0, 30.0))
    best = est.estimate(turned, camera=camera).best
    assert abs(best.inplane_deg - 20.0) < 5.0
    plain = PoseEstimator().fit(images, az, boxes=boxes, object_height_m=0.1).set_params(
        search__inplane_range_deg=(-30.0, 30.0)).estimate(turned, camera=camera).best
    depth = best.t_cam_obj[2]
    # The origin's image: the box centre plus the offset, scaled and turned with the pose.
    u, v = np.array(best.position) + best.scale * 10.0 * np.array(
        [np.cos(best.inplane), np.sin(best.inplane)])
    np.testing.assert_allclose(best.t_cam_obj[:2], [(u - 63.5) / 400 * depth,
                                                    (v - 63.5) / 400 * depth], atol=1e-9)
    # The same pose and depth without origins; t then names the box centre.
    assert plain.t_cam_obj[2] == pytest.approx(depth)
    np.testing.assert_allclose(plain.t_cam_obj[:2], [(best.position[0] - 63.5) / 400 * depth,
                                                     (best.position[1] - 63.5) / 400 * depth],
                               atol=1e-9)
    # A depth factor per view: the origin at that share of the object's depth.
    deep = PoseEstimator().fit(images, az, boxes=boxes, object_height_m=0.1,
                               origins=np.column_stack([origins, np.full(len(images), 1.25)]))
    deep.set_params(search__inplane_range_deg=(-30.0, 30.0))
    far = deep.estimate(turned, camera=camera).best
    np.testing.assert_allclose(far.t_cam_obj, np.array(best.t_cam_obj) * 1.25, rtol=1e-9)
    with pytest.raises(ValueError, match=r"origins must have shape \(18, 2\) or \(18, 3\)"):
        PoseEstimator().fit(images, az, boxes=boxes, origins=origins[:3])
    with pytest.raises(ValueError, match="origins: row 0 has a depth factor 0"):
        PoseEstimator().fit(images, az, boxes=boxes,
                            origins=np.column_stack([origins, np.zeros(len(images))]))
    with pytest.raises(ValueError, match="the model's have 2 columns, the new views' 3"):
        est.partial_fit(images[:1], az[:1], boxes=boxes[:1], origins=[[1.0, 2.0, 1.0]])
    bad = origins.copy()
    bad[4, 1] = np.nan
    with pytest.raises(ValueError, match="origins: row 4 is not finite"):
        PoseEstimator().fit(images, az, boxes=boxes, origins=bad)
    with pytest.raises(ValueError, match="exactly when the model was fitted with them"):
        est.partial_fit(images[:1], az[:1], boxes=boxes[:1])


def test_extending_with_origins_equals_training_on_everything(synthetic_training):
    from posevote import PoseEstimator
    from posevote.geometry import box_centre

    images, az, boxes = synthetic_training
    origins = np.column_stack([np.array([box_centre(b) for b in boxes])
                               + np.column_stack([np.arange(18.0), -np.arange(18.0) / 2]),
                               1.0 + np.arange(18.0) / 100])
    whole = PoseEstimator().fit(images, az, boxes=boxes, origins=origins)
    grown = PoseEstimator().fit(images[:10], az[:10], boxes=boxes[:10],
                                origins=origins[:10]).partial_fit(
        images[10:], az[10:], boxes=boxes[10:], origins=origins[10:])
    np.testing.assert_allclose(grown.full_model_.view_origin, whole.full_model_.view_origin,
                               atol=1e-9)
    with pytest.raises(ValueError, match="exactly when the model was fitted with them"):
        PoseEstimator().fit(images[:10], az[:10], boxes=boxes[:10]).partial_fit(
            images[10:], az[10:], boxes=boxes[10:], origins=origins[10:])


def test_extending_needs_what_can_be_redone(synthetic_training):
    from posevote import NotFittedError, PoseEstimator
    from posevote.appearance import AppearanceOptions

    images, az, boxes = synthetic_training
    with pytest.raises(NotFittedError):
        PoseEstimator().partial_fit(images[:1], az[:1])
    looked = PoseEstimator(appearance=AppearanceOptions()).fit(images, az, boxes=boxes)
    with pytest.raises(ValueError, match="fit it again on all the images"):
        looked.partial_fit(images[:1], az[:1])
    with pytest.raises(TypeError, match="single"):
        PoseEstimator().fit(images, az).partial_fit("folder", az[:1])


def test_a_levels_model_is_the_views_shrunk_and_grows_with_them(synthetic_training, tmp_path):
    import cv2

    from posevote import PoseEstimator
    from posevote.geometry import box_centre
    from posevote.inference.setup import SearchOptions

    images, az, boxes = synthetic_training
    masks = [img > 0.05 for img in images]
    origins = np.array([box_centre(b) for b in boxes]) + [4.0, -2.0]
    levels = SearchOptions(image_levels=(2.0, 1.0))
    whole = PoseEstimator(search=levels).fit(images, az, boxes=boxes, masks=masks,
                                             origins=origins)
    [(level, small)] = whole.shrunk_models_
    # The same as a model fitted on the images halved, their boxes, masks and origins with them.
    size = (images[0].shape[1] // 2, images[0].shape[0] // 2)
    halved = PoseEstimator().fit(
        [cv2.resize(i, size, interpolation=cv2.INTER_AREA) for i in images], az,
        boxes=np.column_stack([(boxes[:, :2] + 0.5) / 2 - 0.5, boxes[:, 2:] / 2]),
        masks=[cv2.resize(m.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
               for m in masks], origins=(origins + 0.5) / 2 - 0.5)
    assert level == 2.0 and halved.shrunk_models_ == ()
    for name in ("xy", "theta", "weight", "view_box", "view_origin", "view_outline"):
        np.testing.assert_allclose(getattr(small.full_model, name),
                                   getattr(halved.full_model_, name), err_msg=name)
    # Saved, loaded and grown with more views: what a fit on all of them learns.
    PoseEstimator(search=levels).fit(images[:10], az[:10], boxes=boxes[:10], masks=masks[:10],
                                     origins=origins[:10]).save(tmp_path / "m.npz")
    grown = PoseEstimator.load(tmp_path / "m.npz").partial_fit(
        images[10:], az[10:], boxes=boxes[10:], masks=masks[10:], origins=origins[10:])
    [(level, more)] = grown.shrunk_models_
    assert level == 2.0
    for name in ("xy", "theta", "weight", "view_box", "view_origin"):
        np.testing.assert_allclose(getattr(more.full_model, name),
                                   getattr(small.full_model, name), atol=1e-9, err_msg=name)


def test_a_view_too_small_for_its_level_is_named_with_the_level():
    from posevote import PoseEstimator
    from posevote.inference.setup import SearchOptions

    # A faint thin cross: edges as given, none once area-averaged to a quarter.
    img = np.zeros((64, 64))
    img[20:44, 31] = img[31, 20:44] = 0.4
    assert PoseEstimator().fit([img, img], [0.0, 1.0]).model_.n_features > 0
    with pytest.raises(ValueError, match=r"images\[0\] \(shrunk by 4 .* leave the level out of "
                                         r"search.image_levels.*\): no edges found"):
        PoseEstimator(search=SearchOptions(image_levels=(4.0, 1.0))).fit([img, img], [0.0, 1.0])
