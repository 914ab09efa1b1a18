import numpy as np
import pytest

from posevote import NotFittedError, PoseEstimator
from posevote.geometry import angular_error


def test_estimates_between_training_views(fitted_estimator, draw):
    from posevote.data import object_box

    for truth in (50.0, 135.0, 290.0):
        img = draw(np.radians(truth))
        result = fitted_estimator.estimate(img)
        assert result.found and result.best is result.modes[0]
        # half the 20-degree training spacing is what a nearest view could do
        assert np.degrees(angular_error(result.best.azimuth, np.radians(truth))) < 10.0
        x, y, w, h = object_box(img)
        assert result.best.position == pytest.approx((x + (w - 1) / 2, y + (h - 1) / 2), abs=6.0)


def test_finds_shifted_rotated_scaled_object(synthetic_training, draw):
    images, az, boxes = synthetic_training
    est = PoseEstimator(inplane_range_deg=(-20, 20), scale_range=(0.8, 1.25), scale_steps=4)
    est.fit(images, az, boxes=boxes)
    truth = np.radians(100.0)
    img = draw(truth, scale=1.1, inplane=np.radians(12), centre=(70.0, 60.0))
    best = est.estimate(img).best
    assert np.degrees(angular_error(best.azimuth, truth)) < 12
    assert best.inplane_deg == pytest.approx(12.0, abs=5.0)
    assert best.scale == pytest.approx(1.1, abs=0.1)


def test_same_input_same_output(fitted_estimator, draw):
    img = draw(np.radians(77.0))
    a, b = fitted_estimator.estimate(img), fitted_estimator.estimate(img)
    assert a.best == b.best and a.modes == b.modes


def test_threads_give_the_same_estimate(synthetic_training, draw):
    # Threads only change how many viewpoints are probed at once; the per-scale
    # maps (object_kernel) and the local refinement take the same path.
    images, az, boxes = synthetic_training
    est = PoseEstimator(object_kernel=True, chance_correction=True, local_refinement=True,
                        scale_steps=3).fit(images, az, boxes=boxes)
    img = draw(np.radians(143.0))
    one = est.estimate(img)
    two = est.set_params(n_jobs=2).estimate(img)
    assert one.found and two.best == one.best and two.modes == one.modes


def test_appearance_refine_takes_the_nearest_training_view(synthetic_training, draw, tmp_path):
    from posevote.data import object_box
    from posevote.geometry import box_iou

    images, az, boxes = synthetic_training
    est = PoseEstimator(appearance_refine=True).fit(images, az, boxes=boxes)
    assert est.box_regressor_.shape[1] == 4
    img = draw(np.radians(110.0))
    best = est.estimate(img).best
    # The viewpoint is a training view's (110 degrees lies between 100 and 120),
    # and the regressed box still holds the object.
    assert np.min(np.abs(np.degrees(best.azimuth) - np.array([100.0, 120.0]))) < 1e-6
    assert box_iou(best.box, object_box(img)) > 0.7
    x, y, w, h = best.box
    assert best.position == pytest.approx((x + (w - 1) / 2, y + (h - 1) / 2))
    est.save(tmp_path / "m.npz")
    again = PoseEstimator.load(tmp_path / "m.npz")
    np.testing.assert_array_equal(again.box_regressor_, est.box_regressor_)
    assert again.estimate(img).best == best
    # With the verification, the candidates are judged on their regressed boxes.
    verified = again.set_params(verify_candidates=5).estimate(img).best
    assert verified is not None and box_iou(verified.box, object_box(img)) > 0.7
    # With the jittered boxes' medoid view, still a training view near the truth.
    jittered = again.set_params(verify_candidates=0, appearance_jitter=0.05).estimate(img).best
    assert jittered is not None and jittered.box == best.box
    assert np.min(np.abs(np.degrees(jittered.azimuth) - np.array([100.0, 120.0]))) < 1e-6
    plain = PoseEstimator().fit(images[:4], az[:4], boxes=boxes[:4])
    for extra in ({}, {"verify_candidates": 5}):
        with pytest.raises(ValueError, match="appearance_refine needs the box regression"):
            plain.set_params(appearance_refine=True, **extra).estimate(img)


def test_appearance_refine_keeps_the_verified_box(synthetic_training, draw, monkeypatch):
    import posevote.estimator as estimator_module

    images, az, boxes = synthetic_training
    est = PoseEstimator(appearance_refine=True, verify_candidates=5).fit(images, az,
                                                                       boxes=boxes)
    img = draw(np.radians(110.0))
    real = estimator_module.verify_candidates
    chosen = []

    def spy(*args, **kwargs):
        found = real(*args, **kwargs)
        assert found is not None
        chosen.append(found[2])
        return found

    monkeypatch.setattr(estimator_module, "verify_candidates", spy)
    best = est.estimate(img).best
    # The winner's regressed box is the estimate's, not the re-found mode's regressed anew.
    assert len(chosen) == 1 and best is not None and best.box == pytest.approx(chosen[0])


def test_blank_image_is_not_found(fitted_estimator):
    result = fitted_estimator.estimate(np.zeros((64, 64)))
    assert not result.found and result.best is None and result.modes == ()


def test_save_load_round_trip(fitted_estimator, draw, tmp_path):
    path = tmp_path / "model.npz"
    fitted_estimator.save(path)
    loaded = PoseEstimator.load(path)
    assert loaded.get_params() == fitted_estimator.get_params()
    img = draw(np.radians(200.0))
    assert loaded.estimate(img).best == fitted_estimator.estimate(img).best


def test_unfitted_raises():
    with pytest.raises(NotFittedError, match="not fitted"):
        PoseEstimator().estimate(np.zeros((8, 8)))
    with pytest.raises(NotFittedError, match="not fitted"):
        PoseEstimator().save("x.npz")


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"position_sigma": -1}, "position_sigma must be a positive number"),
        ({"scale_range": (1.2, 0.8)}, "scale_range"),
        ({"inplane_range_deg": (10, -10)}, "inplane_range_deg"),
        ({"scale_steps": 0}, "scale_steps must be an integer"),
        ({"clutter_sigma": 0}, "clutter_sigma"),
        ({"coherence_floor": 1.5}, "coherence_floor"),
        ({"density_cap": 0}, "density_cap must be positive"),
        ({"fit_radius_steps": 0.0}, "fit_radius_steps must be a positive number"),
        ({"fit_view_shape": float("nan")}, "fit_view_shape must be a positive number"),
        ({"refine_modes": 0}, "refine_modes must be an integer >= 1"),
        ({"refine_scale_steps": 0.0}, "refine_scale_steps must be positive or None"),
        ({"refine_scale_steps": float("nan")}, "refine_scale_steps must be positive or None"),
        ({"contrast": 2}, "contrast must be in"),
        ({"viewpoint_step_deg": -5}, "viewpoint_step_deg must be positive"),
        ({"prune": "harsh"}, "unknown pruning preset"),
        ({"prune_pose_std_deg": -1.0}, "pruning knobs must be positive"),
        ({"instance_margin": 0.5}, "instance_margin must be >= 1"),
        ({"max_search_features": 0}, "max_search_features must be an integer >= 1 or None"),
        ({"max_voters": 2.5}, "max_voters must be an integer >= 1 or None"),
        ({"verify_candidates": -1}, "verify_candidates must be an integer >= 0"),
        ({"verify_margin": 5.0}, "verify_margin must be in"),
        ({"verify_overlap": 1.0}, "verify_overlap must be in"),
        ({"verify_shortlist": 0}, "verify_shortlist must be an integer >= 1"),
        ({"n_jobs": 0}, "n_jobs must be an integer >= 1"),
        ({"appearance_window_deg": 0.0}, "appearance_window_deg must be a positive number"),
        ({"verify_tolerance_deg": 200.0}, "verify_tolerance_deg must be in"),
        ({"verify_objectness_weight": -1.0}, "verify_objectness_weight must be a finite"),
        ({"verify_objectness_weight": float("nan")}, "verify_objectness_weight must be a finite"),
        ({"appearance_jitter": -0.1}, "appearance_jitter must be in"),
        ({"appearance_jitter": 0.5}, "appearance_jitter must be in"),
        ({"appearance_jitter": float("nan")}, "appearance_jitter must be in"),
    ],
)
def test_bad_parameters(synthetic_training, kwargs, message):
    images, az, boxes = synthetic_training
    with pytest.raises(ValueError, match=message):
        PoseEstimator(**kwargs).fit(images[:2], az[:2])


def test_set_params_rejects_unknown():
    with pytest.raises(ValueError, match="unknown parameter 'sigma'"):
        PoseEstimator().set_params(sigma=1)


def test_bad_training_input(synthetic_training):
    images, az, boxes = synthetic_training
    est = PoseEstimator()
    with pytest.raises(ValueError, match="at least one"):
        est.fit([], [])
    with pytest.raises(ValueError, match="poses must have shape"):
        est.fit(images[:2], az[:3])
    with pytest.raises(ValueError, match="row 1 is not finite"):
        est.fit(images[:2], [0.0, np.nan])
    with pytest.raises(ValueError, match=r"images\[0\]: box .* is not inside"):
        est.fit(images[:1], az[:1], boxes=[[100, 100, 50, 50]])
    with pytest.raises(ValueError, match=r"images\[0\]: no edges found"):
        est.fit([np.zeros((32, 32))], [0.0])
    with pytest.raises(ValueError, match="boxes must have 2 rows"):
        est.fit(images[:2], az[:2], boxes=[[0, 0, 5, 5]])
    with pytest.raises(ValueError, match="mask shape"):
        est.fit(images[:1], az[:1], masks=[np.ones((3, 3), bool)])


def test_masks_and_instances(synthetic_training):
    images, az, _ = synthetic_training
    masks = [im > 0.05 for im in images]
    est = PoseEstimator().fit(images, az, masks=masks, instances=["a"] * 9 + ["b"] * 9)
    assert est.model_.instance_names == ("a", "b")
    assert est.model_.n_views == 18


def test_appearance_descriptors_from_boxes_or_masks_agree(synthetic_training):
    # With every box given, the descriptors are computed image by image; with
    # boxes from masks, after all of them are known: the same boxes give the
    # same descriptors and classifier.
    images, az, boxes = synthetic_training
    masks = []
    for x, y, w, h in boxes:
        m = np.zeros(images[0].shape, bool)
        m[int(y):int(y + h), int(x):int(x + w)] = True
        masks.append(m)
    mask_boxes = np.array([[np.nonzero(m)[1].min(), np.nonzero(m)[0].min(),
                            np.ptp(np.nonzero(m)[1]) + 1, np.ptp(np.nonzero(m)[0]) + 1]
                           for m in masks], dtype=float)
    a = PoseEstimator().fit(images, az, boxes=mask_boxes)
    b = PoseEstimator().fit(images, az, masks=masks)
    assert a.descriptor_window_ == b.descriptor_window_
    np.testing.assert_array_equal(a.view_descriptors_, b.view_descriptors_)
    assert (a.objectness_ is None) == (b.objectness_ is None)
    if a.objectness_ is not None:
        np.testing.assert_allclose(a.objectness_, b.objectness_)


def test_weights_and_fitting_switch_off(synthetic_training, draw):
    images, az, boxes = synthetic_training
    est = PoseEstimator(weights=False, fitting=False, local_refinement=False)
    est.fit(images, az, boxes=boxes)
    best = est.estimate(draw(np.radians(40.0))).best
    assert not best.refined
    assert best.azimuth_deg % 20 == pytest.approx(0.0, abs=1e-6) or \
        best.azimuth_deg % 20 == pytest.approx(20.0, abs=1e-6)


def test_local_refinement_ranks_the_refined_modes(synthetic_training, draw):
    images, az, boxes = synthetic_training
    est = PoseEstimator(local_refinement=True, refine_modes=3).fit(images, az, boxes=boxes)
    truth = np.radians(130.0)
    result = est.estimate(draw(truth))
    assert len(result.modes) >= 2
    n = min(3, len(result.modes))
    scores = [m.score for m in result.modes[:n]]
    assert scores == sorted(scores, reverse=True)
    assert np.degrees(angular_error(result.best.azimuth, truth)) < 10.0


def test_coil_instance_real_data(coil_dir):
    from posevote.data import read_coil

    train = read_coil(coil_dir, objects=[6], azimuths_deg=range(0, 360, 20))
    test = read_coil(coil_dir, objects=[6], azimuths_deg=[45, 130, 255])
    est = PoseEstimator().fit(train.load_images(), train.poses, boxes=train.boxes)
    errors = [np.degrees(angular_error(est.estimate(img).best.azimuth, pose[0]))
              for img, pose in zip(test.load_images(), test.poses, strict=True)]
    assert np.median(errors) < 5.0


def _marked(img):
    """Instance 'b': the same object with an extra bar across its top."""
    import cv2

    out = img.copy()
    cv2.line(out, (44, 40), (84, 40), 0.15, 2, cv2.LINE_AA)
    return out


def test_category_model_recognises_the_instance(synthetic_training, draw, tmp_path):
    images, az, boxes = synthetic_training
    from posevote.data import object_box

    marked = [_marked(im) for im in images]
    # The paper's recognition (scored at the category's modes, refined near
    # them). With instance_search this toy's barred instance loses: its own
    # search fits scale 0.82 and leaves the bar unexplained (docs/TUNING.md).
    est = PoseEstimator(prune="moderate", instance_margin=1.02, instance_search=False)
    est.fit(images + marked, np.concatenate([az, az]),
            boxes=np.vstack([boxes, [object_box(im) for im in marked]]),
            instances=["a"] * 18 + ["b"] * 18)
    assert est.model_.n_features < est.full_model_.n_features
    truth = np.radians(70.0)
    result = est.estimate(_marked(draw(truth)))
    assert result.instance == "b" and result.instance_margin >= 1.02
    assert np.degrees(angular_error(result.best.azimuth, truth)) < 10
    est.save(tmp_path / "cat.npz")
    loaded = PoseEstimator.load(tmp_path / "cat.npz")
    assert loaded.full_model_.n_features == est.full_model_.n_features
    assert loaded.model_.n_features == est.model_.n_features
    assert loaded.estimate(_marked(draw(truth))).best == result.best
    off = PoseEstimator(recognize_instance=False).fit(images, az, boxes=boxes,
                                                      instances=["a"] * 9 + ["b"] * 9)
    plain = off.estimate(draw(truth))
    assert plain.instance == "" and np.isnan(plain.instance_margin)


def test_object_kernel_and_density_options(synthetic_training, draw):
    images, az, boxes = synthetic_training
    est = PoseEstimator(object_kernel=True, contrast=1.0, density_cap=1.0,
                        scale_range=(0.8, 1.25), scale_steps=4, viewpoint_step_deg=20)
    est.fit(images, az, boxes=boxes)
    from posevote.data import object_box

    truth = np.radians(100.0)
    img = draw(truth, scale=1.15, centre=(66.0, 60.0))
    best = est.estimate(img).best
    assert np.degrees(angular_error(best.azimuth, truth)) < 12
    assert best.scale == pytest.approx(1.15, abs=0.1)
    x, y, w, h = object_box(img)
    assert best.position == pytest.approx((x + (w - 1) / 2, y + (h - 1) / 2), abs=5.0)


def test_local_refinement_in_object_units(synthetic_training, draw):
    from posevote.data import object_box

    # Without narrow_scale this estimate ends at scale 0.70: the search's
    # wide kernel does not tell 0.85 from the smallest scale.

    images, az, boxes = synthetic_training
    est = PoseEstimator(object_kernel=True, chance_correction=True, density_cap=0.5,
                        local_refinement=True, narrow_scale=True,
                        inplane_range_deg=(-20, 20), scale_range=(0.7, 1.3), scale_steps=5)
    est.fit(images, az, boxes=boxes)
    truth = np.radians(70.0)
    img = draw(truth, scale=0.85, inplane=np.radians(-8.0), centre=(70.0, 62.0))
    best = est.estimate(img).best
    assert best.refined
    assert np.degrees(angular_error(best.azimuth, truth)) < 10
    assert best.scale == pytest.approx(0.85, rel=0.06)
    assert best.inplane_deg == pytest.approx(-8.0, abs=3.0)
    x, y, w, h = object_box(img)
    assert best.position == pytest.approx((x + (w - 1) / 2, y + (h - 1) / 2), abs=2.5)


def test_interpolated_alignment_keeps_the_azimuth(synthetic_training, draw):
    from posevote.data import object_box

    images, az, boxes = synthetic_training
    est = PoseEstimator(local_refinement=True, inplane_range_deg=(-20, 20),
                        scale_range=(0.8, 1.2)).fit(images, az, boxes=boxes)
    truth = np.radians(70.0)  # halfway between the training views at 60 and 80 degrees
    img = draw(truth, scale=1.1, inplane=np.radians(6.0), centre=(62.0, 66.0))
    plain = est.estimate(img).best
    between = est.set_params(interpolate_alignment=True).estimate(img).best
    assert between.refined and between.azimuth == plain.azimuth
    assert between.score > 0
    x, y, w, h = object_box(img)
    assert between.position == pytest.approx((x + (w - 1) / 2, y + (h - 1) / 2), abs=3.0)
    assert between.inplane_deg == pytest.approx(6.0, abs=4.0)


def _barred(img):
    """A small instance: a bar across the upper quarter of the object's box."""
    import cv2

    from posevote.data import object_box

    x, y, w, h = (int(v) for v in object_box(img))
    out = img.copy()
    cv2.line(out, (x, y + h // 4), (x + w - 1, y + h // 4), 0.15, 2, cv2.LINE_AA)
    return out


def test_instance_search_finds_a_small_instance_at_its_own_size(draw):
    from posevote.data import object_box

    az = np.radians(np.arange(0, 360, 20))
    images = [draw(a) for a in az] + [_barred(draw(a, scale=0.6)) for a in az]
    boxes = np.array([object_box(im) for im in images])
    est = PoseEstimator(instance_search=True, instance_margin=1.02)
    est.fit(images, np.concatenate([az, az]), boxes=boxes, instances=["big"] * 18 + ["small"] * 18)
    small = est.full_model_.size_of(1)
    assert small == pytest.approx(0.75, abs=0.03)  # 0.6 of the big one; reference: their mean
    truth = np.radians(70.0)
    result = est.estimate(_barred(draw(truth, scale=0.6)))
    assert result.instance == "small" and result.instance_margin >= 1.02
    assert np.degrees(angular_error(result.best.azimuth, truth)) < 10
    # The instance searched its own scale grid (0.9-1.1 times its size),
    # below the category grid (0.9-1.1); the fit may leave it a little.
    assert result.best.scale == pytest.approx(small, rel=0.15)


def test_verification_keeps_the_search_near_the_verified_box(synthetic_training, draw):
    from posevote.geometry import box_iou

    images, az, boxes = synthetic_training
    scene = np.zeros((200, 260))
    scene[30:158, 70:198] = draw(np.radians(100))
    est = PoseEstimator(verify_candidates=5).fit(images, az, boxes=boxes)
    feats, shape, img = est._read(scene)
    maps = est._search_maps(feats, shape)
    probes = est._probe(maps, None)
    kept = []
    for overlap in (0.0, 0.9):
        est.set_params(verify_overlap=overlap)
        located = est._verify(probes, img, feats, maps)
        assert located is not None
        again = located[2]
        kept.append(again.boxes()[again.score > 0])
    assert len(kept[1]) < len(kept[0])
    # Every kept box overlaps the verified one by 0.9, hence each other by about 0.8.
    assert np.all(box_iou(kept[1][:, None, :], kept[1][None, :, :]) > 0.75)


def test_verification_tolerance_reaches_the_comparison(synthetic_training, draw, monkeypatch):
    import posevote.estimator as estimator_module
    from posevote.refinement.fitting import probe_spacing

    images, az, boxes = synthetic_training
    est = PoseEstimator(verify_candidates=5).fit(images, az, boxes=boxes)
    seen = []

    def spy(*args, tolerance, **kwargs):
        seen.append(tolerance)
        return None   # nothing verified: the estimate goes on with the search's probes

    monkeypatch.setattr(estimator_module, "verify_candidates", spy)
    img = draw(np.radians(100))
    est.estimate(img)
    est.set_params(verify_tolerance_deg=40.0).estimate(img)
    assert seen[0] == pytest.approx(probe_spacing(est.probe(img)[0]))
    assert seen[1] == pytest.approx(np.radians(40.0))
