from dataclasses import replace

import numpy as np
import pytest

from posevote.inference.probes import ProbeSet
from posevote.inference.search import viewpoint_grid
from posevote.inference.setup import SearchOptions


def test_viewpoint_grid_subdivides_turntable(fitted_estimator):
    model = fitted_estimator.model_
    az, el = viewpoint_grid(model)
    assert np.allclose(np.degrees(az), np.arange(0, 360, 20))
    az2, _ = viewpoint_grid(model, subdivisions=2)
    assert np.allclose(np.degrees(np.sort(az2)), np.arange(0, 360, 10))


def test_probes_peak_near_the_truth(fitted_estimator, draw):
    probes, feats = fitted_estimator.probe(draw(np.radians(100)))
    assert len(feats) > 0
    profile = probes.score.max(axis=(1, 2))
    assert abs(np.degrees(probes.azimuth[np.argmax(profile)]) - 100) <= 20
    assert probes.translation.shape == probes.score.shape + (2,)


def test_viewpoint_grid_regular_step(fitted_estimator):
    az, el = viewpoint_grid(fitted_estimator.model_, step=np.radians(30))
    assert np.allclose(np.degrees(az), np.arange(0, 360, 30)) and np.all(el == 0)


def test_per_scale_maps_and_chance_correction(fitted_estimator, draw):
    from posevote.features.edges import extract_edges
    from posevote.inference.search import probe_poses
    from posevote.inference.setup import _search_image_maps
    from posevote.scoring.maps import scaled_features

    est = fitted_estimator
    image = draw(np.radians(60))
    feats, shape = extract_edges(image, est.edges, training=False), image.shape
    scales = np.array([0.9, 1.1])

    def maps_for(options):
        setup = replace(est.setup(), options=options)
        return [_search_image_maps(*scaled_features(feats, shape, s), setup, sigma=3.0, scale=s)
                for s in scales]

    kw = dict(azimuths=np.radians([40.0, 60.0]), elevations=np.zeros(2), inplanes=np.zeros(1),
              scales=scales, viewpoint_kappa=est.viewpoint_kappa_)
    raw = probe_poses(est.model_, maps_for(SearchOptions(object_kernel=True)), **kw)
    corrected = probe_poses(est.model_, maps_for(SearchOptions(object_kernel=True,
                                                               chance_correction=True)), **kw)
    # The local chance level only takes away, and the object still scores.
    assert np.all(corrected.score <= raw.score + 1e-9) and corrected.score.max() > 0
    assert not np.allclose(corrected.score, raw.score)
    with pytest.raises(ValueError, match="one TestMaps per scale"):
        probe_poses(est.model_, maps_for(SearchOptions())[:1], **kw)


def test_probe_boxes_are_the_viewpoint_box_at_each_scale_around_each_translation():
    translation = np.zeros((2, 1, 2, 2))
    translation[1, 0, 1] = (50.0, 40.0)
    probes = ProbeSet(azimuth=np.zeros(2), elevation=np.zeros(2), inplane=np.zeros(1),
                      scale=np.array([1.0, 2.0]), score=np.ones((2, 1, 2)),
                      translation=translation, box=np.array([[10.0, 6.0], [20.0, 8.0]]))
    boxes = probes.boxes()
    assert boxes.shape == (2, 1, 2, 4)
    assert np.allclose(boxes[1, 0, 1], (30.0, 32.0, 40.0, 16.0))
    assert np.allclose(boxes[0, 0, 0], (-5.0, -3.0, 10.0, 6.0))


def test_threads_give_the_same_probes(fitted_estimator, draw):
    from posevote.features.edges import extract_edges
    from posevote.inference.search import probe_poses
    from posevote.model.kernels import ORIENTATION_KAPPA
    from posevote.scoring.maps import prepare_test

    est = fitted_estimator
    image = draw(np.radians(130))
    feats = extract_edges(image, est.edges, training=False)
    maps = prepare_test(feats, image.shape, position_sigma=3.0, orientation_kappa=ORIENTATION_KAPPA,
                        edge_spacing=est.edges.spacing)
    az, el = viewpoint_grid(est.model_)
    kw = dict(azimuths=az, elevations=el, inplanes=np.radians([-10.0, 0.0, 10.0]),
              scales=np.array([0.9, 1.0, 1.1]), viewpoint_kappa=est.viewpoint_kappa_)
    calls = []
    one = probe_poses(est.model_, maps, **kw)
    three = probe_poses(est.model_, maps, n_threads=3, progress=calls.append, **kw)
    assert one.score.any() and len(calls) == len(az)
    np.testing.assert_array_equal(three.score, one.score)
    np.testing.assert_array_equal(three.translation, one.translation)
    np.testing.assert_array_equal(three.box, one.box)
    with pytest.raises(ValueError, match="n_threads must be an integer >= 1"):
        probe_poses(est.model_, maps, n_threads=0, **kw)


def test_the_search_features_of_a_viewpoint_are_kept_per_model(fitted_estimator):
    from posevote.inference.search import _PROBE_CACHE, _probe_features
    from posevote.inference.voting import strongest_voters
    from posevote.scoring.score import subsample_features, viewpoint_features

    est = fitted_estimator
    model, kappa = est.model_, est.viewpoint_kappa_
    kw = dict(viewpoint_kappa=kappa, use_weights=True, k1_cutoff=0.1, max_voters=3)
    first = _probe_features(model, 0.5, 0.0, max_features=7, **kw)
    feats = viewpoint_features(model, 0.5, 0.0, viewpoint_kappa=kappa, use_weights=True,
                               k1_cutoff=0.1)
    sub = subsample_features(feats.xy, feats.theta, feats.weight, 7)
    for got, want in zip(first, (*sub, feats.box, strongest_voters(sub[2], 3)), strict=True):
        np.testing.assert_array_equal(got, want)
    assert len(first[4]) == 3
    assert _probe_features(model, 0.5, 0.0, max_features=7, **kw)[0] is first[0]
    # Another budget or viewpoint is another entry.
    assert len(_probe_features(model, 0.5, 0.0, max_features=None, **kw)[1]) > 7
    assert len(_PROBE_CACHE[model]) >= 2


def test_a_search_near_a_pose_probes_the_scales_near_its_own(fitted_estimator, draw):
    from posevote.features.edges import extract_edges
    from posevote.inference.search import near_scales, probe
    from posevote.inference.setup import search_maps
    from posevote.results import Hypothesis

    est = fitted_estimator
    options = SearchOptions(scale_range=(0.7, 1.45), scale_steps=6, object_kernel=True)
    grid = options.grid()[1]
    # 1.5 grid steps either side of the pose's scale; all when under two are near.
    assert near_scales(grid, float(grid[2]), options).tolist() == [1, 2, 3]
    assert near_scales(grid, 0.3, options).tolist() == list(range(6))
    setup = replace(est.setup(), options=options)
    image = draw(np.radians(60))
    feats = extract_edges(image, est.edges, training=False)
    maps = search_maps(feats, image.shape, est.model_, setup)
    near = Hypothesis(azimuth=np.radians(60.0), elevation=0.0, inplane=0.0,
                      scale=float(grid[2]), position=(64.0, 64.0), box=(20.0, 20.0, 88.0, 88.0),
                      score=0.5, refined=False)
    probes = probe(est.model_, maps, setup, near=near)
    np.testing.assert_array_equal(probes.scale, grid[[1, 2, 3]])
    # Three scales are too few to rank: the search with their maps alone probes them all.
    three = probe(est.model_, [m if k in (1, 2, 3) else None for k, m in enumerate(maps)], setup)
    np.testing.assert_array_equal(probes.score, three.score[np.isin(three.azimuth,
                                                                     probes.azimuth)])
    # Scales without maps are not probed.
    some = [m if k != 3 else None for k, m in enumerate(maps)]
    assert probe(est.model_, some, setup, near=near).scale.tolist() == grid[[1, 2]].tolist()
    # A pose beside the scales that have maps probes those (it used to fail).
    far = [m if k == 5 else None for k, m in enumerate(maps)]
    assert probe(est.model_, far, setup, near=near).scale.tolist() == [grid[5]]
    with pytest.raises(ValueError, match="no maps for the scales to probe"):
        probe(est.model_, [None] * len(maps), setup, near=near)
    with pytest.raises(ValueError, match="one TestMaps \\(or None\\) per scale"):
        probe(est.model_, maps[:2], setup)


def _ranking_search(est, draw, polish):
    """A ranking search (per-scale maps, six scales) of a view drawn at 60 degrees, its
    scales, and what probes every ``step``-th scale at every viewpoint."""
    from posevote.features.edges import extract_edges
    from posevote.inference.search import MAX_VOTERS, VOTE_CANDIDATES, probe, probe_poses
    from posevote.inference.setup import search_maps
    from posevote.model.kernels import K1_CUTOFF

    options = SearchOptions(scale_range=(0.7, 1.45), scale_steps=6, object_kernel=True)
    setup = replace(est.setup(), options=options)
    image = draw(np.radians(60))
    maps = search_maps(extract_edges(image, est.edges, training=False), image.shape, est.model_,
                       setup)
    ranked = probe(est.model_, maps, setup, polish=polish)

    def everywhere(step):
        return probe_poses(est.model_, maps[::step], azimuths=ranked.azimuth,
                           elevations=ranked.elevation, inplanes=ranked.inplane,
                           scales=options.grid()[1][::step],
                           viewpoint_kappa=setup.viewpoint_kappa, k1_cutoff=K1_CUTOFF,
                           max_voters=MAX_VOTERS, n_candidates=VOTE_CANDIDATES, polish=polish)
    return ranked, options.grid()[1], everywhere


@pytest.mark.parametrize("polish", [False, True])
def test_a_ranking_search_probes_the_scales_between_at_the_best_viewpoints(fitted_estimator,
                                                                             draw, polish):
    ranked, scales, probe_all = _ranking_search(fitted_estimator, draw, polish)
    everywhere = probe_all(1)
    np.testing.assert_array_equal(ranked.scale, scales)
    # Every other scale at every viewpoint, as a search of all of them finds it.
    np.testing.assert_array_equal(ranked.score[:, :, ::2], everywhere.score[:, :, ::2])
    # The scales between at the third of the viewpoints that scored best there.
    probed = np.flatnonzero(ranked.score[:, 0, 1::2].any(axis=1))
    best = np.argsort(-everywhere.score[:, :, ::2].max(axis=(1, 2)), kind="stable")[:6]
    assert sorted(probed.tolist()) == sorted(best.tolist())
    np.testing.assert_array_equal(ranked.score[probed][:, :, 1::2],
                                  everywhere.score[probed][:, :, 1::2])
    assert not ranked.score[np.setdiff1d(np.arange(18), probed)][:, :, 1::2].any()
    np.testing.assert_array_equal(ranked.translation[:, :, ::2], everywhere.translation[:, :, ::2])


def test_a_polished_search_on_one_set_of_maps_polishes_near_its_best_viewpoints(
        fitted_estimator, draw):
    # The default preset's search: every viewpoint unpolished, then the
    # viewpoints within the fit's reach of the POLISHED_MODES best polished
    # as a polished search of every viewpoint polishes them.
    from posevote.features.edges import extract_edges
    from posevote.inference.probes import probe_spacing
    from posevote.inference.search import (
        MAX_VOTERS,
        POLISH_REACH_STEPS,
        POLISHED_MODES,
        VOTE_CANDIDATES,
        probe,
        probe_poses,
    )
    from posevote.inference.setup import search_maps
    from posevote.model.kernels import K1_CUTOFF
    from posevote.refinement.fitting import FIT_RADIUS_STEPS

    assert POLISH_REACH_STEPS == FIT_RADIUS_STEPS
    est = fitted_estimator
    setup = est.setup()
    image = draw(np.radians(60))
    maps = search_maps(extract_edges(image, est.edges, training=False), image.shape, est.model_,
                       setup)
    probes = probe(est.model_, maps, setup)
    kw = dict(azimuths=probes.azimuth, elevations=probes.elevation, inplanes=probes.inplane,
              scales=probes.scale, viewpoint_kappa=setup.viewpoint_kappa, k1_cutoff=K1_CUTOFF,
              max_voters=MAX_VOTERS, n_candidates=VOTE_CANDIDATES)
    rough = probe_poses(est.model_, maps, polish=False, **kw)
    fine = probe_poses(est.model_, maps, polish=True, **kw)
    top = np.argsort(-rough.score.max(axis=(1, 2)), kind="stable")[:POLISHED_MODES]
    d = rough.directions
    near = (d @ d[top].T >= np.cos(POLISH_REACH_STEPS * probe_spacing(rough))).any(axis=1)
    assert 3 <= near.sum() < len(near)
    np.testing.assert_array_equal(probes.score[near], fine.score[near])
    np.testing.assert_array_equal(probes.translation[near], fine.translation[near])
    np.testing.assert_array_equal(probes.score[~near], rough.score[~near])
    np.testing.assert_array_equal(probes.translation[~near], rough.translation[~near])
    # The best probe is the polished search's.
    assert probes.score.max() == fine.score.max()


def test_coarse_viewpoints_cover_the_set_at_their_separation():
    from posevote.geometry import viewing_direction
    from posevote.inference.search import coarse_viewpoints

    el, az = np.meshgrid(np.radians(np.arange(-30.0, 61.0, 7.5)), np.radians(np.arange(0, 360, 10)))
    az, el = az.ravel(), el.ravel()
    sep = np.radians(15.0)
    kept = coarse_viewpoints(az, el, sep)
    d = viewing_direction(az, el)
    between = np.degrees(np.arccos(np.clip(d[kept] @ d[kept].T, -1, 1)))
    np.fill_diagonal(between, 180.0)
    assert between.min() >= 15.0 - 1e-6 and 60 < len(kept) < len(az) / 3
    to_kept = np.degrees(np.arccos(np.clip((d @ d[kept].T).max(axis=1), -1, 1)))
    assert to_kept.max() <= 15.0 + 1e-6
    assert kept.tolist() == coarse_viewpoints(az, el, sep).tolist()


def test_a_ranking_search_on_the_sphere_goes_coarse_to_fine(synthetic_training, draw):
    # Views at three elevations: the every-other scales probed first at the
    # coarse viewpoints, then at the others near the best third of those.
    from posevote import PoseEstimator
    from posevote.inference.search import COARSE_STEPS, RANKING_VIEWPOINTS, coarse_viewpoints

    images, az, boxes = synthetic_training
    rows = np.radians([-15.0, 0.0, 15.0])
    poses = np.array([(a, e) for e in rows for a in az])
    est = PoseEstimator().fit(list(images) * 3, poses, boxes=np.tile(boxes, (3, 1)))
    ranked, _, probe_all = _ranking_search(est, draw, polish=False)
    everywhere = probe_all(2)
    d = ranked.directions
    reach = COARSE_STEPS * ranked.spacing
    coarse = coarse_viewpoints(ranked.azimuth, ranked.elevation, reach)
    top = coarse[np.argsort(-everywhere.score[coarse].max(axis=(1, 2)), kind="stable")][
        :max(3, round(len(coarse) * RANKING_VIEWPOINTS))]
    near = (d @ d[top].T >= np.cos(reach) - 1e-9).any(axis=1)
    near[coarse] = True
    assert 3 < near.sum() < len(near)
    np.testing.assert_array_equal(ranked.probed[:, 0, 0], near)
    np.testing.assert_array_equal(ranked.score[near][:, :, ::2], everywhere.score[near])
    assert not ranked.score[~near].any()
    # Unprobed viewpoints keep their boxes for the fit.
    np.testing.assert_array_equal(ranked.box, everywhere.box)


def test_the_search_strategy_follows_what_the_search_is_for():
    from posevote.inference.search import search_strategy

    full = dict(near=False, n_viewpoints=36, n_scales=6)
    assert search_strategy(per_scale=False, polish=True, **full) == "polish near the best"
    assert search_strategy(per_scale=False, polish=False, **full) == "every probe"
    assert search_strategy(per_scale=False, polish=True, **{**full, "near": True}) == \
        "every probe"
    assert search_strategy(per_scale=True, polish=True, **full) == "ranking"
    assert search_strategy(per_scale=True, polish=False, **full) == "ranking"
    assert search_strategy(per_scale=True, polish=True, **{**full, "n_scales": 3}) == \
        "every probe"
    assert search_strategy(per_scale=True, polish=True, **{**full, "n_viewpoints": 5}) == \
        "every probe"
