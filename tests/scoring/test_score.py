"""The scoring layer: the compiled scores agree with their numpy references, and the maps'
density reads as they are tabulated."""

from dataclasses import replace

import numpy as np
import pytest

from posevote.features import EdgeFeatures
from posevote.scoring.maps import prepare_test
from posevote.scoring.score import (
    density_at,
    explained_sums,
    explained_sums_reference,
    gather_score,
    gather_score_reference,
    place_features,
    shifted_score,
)


@pytest.mark.parametrize(("sigma", "block"), [(2.0, 1), (7.0, 3), (9.5, 4)])
@pytest.mark.parametrize("t", [(70.0, 50.0), (71.3, 48.6), (5.0, 5.0), (118.5, 98.7)])
def test_score_kernels_match_reference(vote_scene, t, sigma, block):
    train_xy, train_theta, train_w, alpha, scale, _, maps = vote_scene
    # A wide kernel's maps are on a grid of blocks: odd (centred on a pixel) and even.
    maps = prepare_test(EdgeFeatures(xy=maps.xy, theta=maps.theta), (100, 120),
                        position_sigma=sigma, orientation_kappa=8.0)
    assert maps.grid == block
    got = gather_score(maps.density, maps.frame, train_xy, train_theta, train_w, alpha, scale, *t)
    ref = gather_score_reference(maps, train_xy, train_theta, train_w, alpha, scale, *t)
    assert got == pytest.approx(ref, rel=1e-9, abs=1e-12)
    m = len(train_w)
    px, py, obins, ofrac = np.empty(m), np.empty(m), np.empty((m, 2), np.int64), np.empty(m)
    place_features(maps.frame, maps.density.shape[0], train_xy, train_theta, alpha, scale,
                   t[0] - 2, t[1] + 1, px, py, obins, ofrac)
    assert shifted_score(maps.density, maps.frame, train_w, px, py, obins, ofrac, 2, -1, 1
                         ) == pytest.approx(got, rel=1e-9, abs=1e-12)


def test_density_options_and_chance(vote_scene):
    from posevote.scoring.maps import scaled_features

    *_, maps = vote_scene
    assert maps.chance == pytest.approx(float(maps.density.mean()))
    # On a coarse grid, the mean of phi read at every pixel.
    wide = prepare_test(EdgeFeatures(xy=maps.xy, theta=maps.theta), (100, 120),
                        position_sigma=9.5, orientation_kappa=8.0)
    v, u = np.mgrid[0:100, 0:120]
    pixels = np.stack([u.ravel(), v.ravel()], axis=1).astype(float)
    everywhere = replace(wide, window=(0.0, 0.0, 120.0, 100.0))
    read = [density_at(everywhere, pixels, np.full(len(pixels), th))
            for th in (np.arange(16) + 0.5) * np.pi / 16]
    assert wide.chance == pytest.approx(float(np.mean(read)), rel=1e-6)
    assert 0 < maps.chance < 0.5
    feats = EdgeFeatures(xy=maps.xy, theta=maps.theta)
    capped = prepare_test(feats, (100, 120), position_sigma=2.0, orientation_kappa=8.0,
                          density_cap=0.5)
    assert capped.density.max() <= 0.5 + 1e-6
    half, shape = scaled_features(feats, (100, 120), 2.0)
    assert shape == (50, 60) and np.allclose(half.xy, feats.xy / 2.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_explained_sums_match_their_reference(seed):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 60, (300, 2))
    xy[10] = xy[11]                      # a repeated point is 0 from its twin
    xy[20:30, 0] = 17.0                  # ties in the sort by x
    theta = rng.uniform(0, np.pi, 300)
    strength = rng.uniform(0, 1, 300)
    test_xy = np.vstack([rng.uniform(-10, 70, (200, 2)), xy[:5] + 0.3])
    test_theta = rng.uniform(0, np.pi, 205)
    got = explained_sums(xy, theta, strength, test_xy, test_theta, 3.0, 8.0)
    want = explained_sums_reference(xy, theta, strength, test_xy, test_theta, 3.0, 8.0)
    assert np.count_nonzero(want) > 100
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
    assert len(explained_sums(xy, theta, strength, np.zeros((0, 2)), np.zeros(0), 3.0, 8.0)) == 0
