"""The test maps: phi's planes, their smoothing on a coarse grid, the merged voters, the window."""

import cv2
import numpy as np
import pytest

from posevote.features import EdgeFeatures
from posevote.geometry import rotate_points
from posevote.inference.voting import accumulate_votes, blur_taps
from posevote.model.kernels import orientation_kernel
from posevote.scoring.maps import (
    _refine,
    _saturate,
    _subtract_plane,
    blurred_points,
    map_grid,
    merge_voters,
    orientation_planes,
    prepare_test,
    restrict_maps,
    saturate_reference,
    smooth,
)
from posevote.scoring.score import density_at, gather_score, gather_score_reference


def test_chance_width_subtracts_the_local_chance_level():
    # An isolated straight contour on the left, dense clutter of every
    # orientation on the right.
    rng = np.random.default_rng(11)
    line = np.stack([np.full(40, 20.0), np.linspace(10, 90, 40)], axis=1)
    clutter = rng.uniform((70, 10), (115, 90), (1500, 2))
    feats = EdgeFeatures(xy=np.vstack([line, clutter]),
                         theta=np.concatenate([np.full(40, np.pi / 2),
                                               rng.uniform(0, np.pi, 1500)]))
    kw = {"position_sigma": 2.0, "orientation_kappa": 8.0, "density_cap": 0.6}
    raw = prepare_test(feats, (100, 120), **kw)
    local = prepare_test(feats, (100, 120), chance_width=8.0, **kw)
    on_line = (slice(None), slice(30, 70), 20)
    in_clutter = (slice(None), slice(30, 70), slice(85, 100))
    # The contour keeps most of its score; the clutter's falls to about nothing.
    assert local.density[on_line].max() > 0.8 * raw.density[on_line].max()
    assert raw.density[in_clutter].mean() > 0.3
    assert abs(local.density[in_clutter].mean()) < 0.05
    assert np.all(local.density <= raw.density + 1e-6)


@pytest.mark.parametrize(("cap", "chance_width"), [(None, None), (0.6, None), (0.6, 8.0),
                                                   (None, 8.0)])
def test_the_saturation_kernels_agree_with_the_numpy_reference(cap, chance_width):
    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 100, (600, 2))
    planes = blurred_points(xy, rng.uniform(0, 1, (16, 600)), (90, 110), 7.0)
    gain = 35.1
    expected = planes.copy()
    saturate_reference(expected, gain, cap, chance_width)
    mean = np.empty(planes.shape[1:], dtype=np.float32)
    _saturate(planes, np.float32(gain), np.float32(-1.0 if cap is None else cap), mean)
    if chance_width is not None:
        _subtract_plane(planes, smooth(mean, chance_width, cv2.BORDER_REFLECT))
    np.testing.assert_array_equal(planes, expected)


@pytest.mark.parametrize("sigma", [2.0, 9.5])
def test_restrict_maps_keeps_the_window_only(sigma):
    # Features only at a few orientations, so that the last orientation bins
    # are empty (the bin bookkeeping must cope).
    rng = np.random.default_rng(5)
    xy = rng.uniform(0, 120, (80, 2))
    theta = rng.choice([0.1, 0.5, 1.0], 80)
    feats = EdgeFeatures(xy=xy, theta=theta)
    kw = {"position_sigma": sigma, "orientation_kappa": 8.0}
    maps = prepare_test(feats, (120, 120), **kw)
    lo, hi = np.array([30.0, 40.0]), np.array([80.0, 90.0])
    sub = restrict_maps(maps, lo, hi)
    assert sub.window == (30.0, 40.0, 80.0, 90.0) and sub.density is maps.density
    inside = np.all((xy >= lo) & (xy <= hi), axis=1)
    alone = prepare_test(feats.select(inside), (120, 120), **kw)
    def per_bin(m):
        return np.bincount(np.minimum((m.vote_theta / np.pi * 16).astype(int), 15), minlength=16)

    np.testing.assert_array_equal(per_bin(sub), per_bin(alone))
    assert np.all(np.diff(sub.vote_theta) >= 0)
    np.testing.assert_allclose(np.sort(sub.xy, axis=0), np.sort(alone.xy, axis=0))
    v, u = np.mgrid[0:120, 0:120]
    pixels = np.stack([u.ravel(), v.ravel()], axis=1).astype(float)
    at = np.full(len(pixels), 0.5)
    read, fresh = density_at(sub, pixels, at), density_at(alone, pixels, at)
    outside = (pixels[:, 0] < 30) | (pixels[:, 1] < 40) | (pixels[:, 0] >= 80) | (pixels[:, 1] >= 90)
    assert not read[outside].any()
    # Away from the window's border phi is the one prepared anew.
    far = np.all((pixels >= lo + 3 * sigma) & (pixels <= hi - 3 * sigma), axis=1)
    np.testing.assert_allclose(read[far], fresh[far], atol=1e-3)
    assert 0 < sub.chance < maps.chance
    if sigma < 6:
        window = maps.density[:, 40:91, 30:81]
        assert sub.chance == pytest.approx(float(window.sum(dtype=np.float64)) / maps.density.size,
                                           rel=1e-12)



@pytest.mark.parametrize(("sigma", "region"), [(1.5, (10, 20, 60, 70)), (2.0, (0, 0, 30, 40)),
                                               (3.2, (95, 80, 140, 125)), (2.0, (-5, -5, 200, 200))])
def test_a_region_holds_the_whole_images_maps_there(sigma, region):
    # Features past the border too (they land on its pixels in both).
    rng = np.random.default_rng(11)
    shape, n = (110, 130), 700
    feats = EdgeFeatures(xy=np.column_stack([rng.uniform(-4, 134, n), rng.uniform(-4, 114, n)]),
                         theta=rng.uniform(0, np.pi, n))
    kw = {"position_sigma": sigma, "orientation_kappa": 8.0}
    whole = prepare_test(feats, shape, **kw)
    part = prepare_test(feats, shape, region=region, **kw)
    u0, v0, u1, v1 = (int(b) for b in part.window)
    assert (u0, v0, u1, v1) == (max(region[0], 0), max(region[1], 0), min(region[2], 129),
                                min(region[3], 109))
    # Only the region is tabulated, from its origin.
    assert part.origin == (u0, v0)
    assert part.density.shape == (whole.density.shape[0], v1 - v0 + 1, u1 - u0 + 1)
    np.testing.assert_allclose(part.density, whole.density[:, v0:v1 + 1, u0:u1 + 1],
                               rtol=0, atol=1e-6)
    # Read through the frame, a pose scores the same inside and nothing outside.
    xy, theta = rng.uniform(-6, 6, (40, 2)), rng.uniform(0, np.pi, 40)
    w = np.full(40, 1.0 / 40)
    for tu, tv in ((0.5 * (u0 + u1), 0.5 * (v0 + v1)), (u0 + 3.3, v1 - 2.7)):
        args = (xy, theta, w, 0.3, 0.9, tu, tv)
        assert gather_score(part.density, part.frame, *args) == pytest.approx(
            gather_score_reference(part, *args), abs=1e-6)
        landed = 0.9 * rotate_points(xy, 0.3) + [tu, tv]
        same = np.all((landed >= [u0, v0]) & (landed < [u1, v1]), axis=1)
        assert gather_score(part.density, part.frame, xy, theta, w * same, 0.3, 0.9, tu, tv) \
            == pytest.approx(gather_score(whole.density, whole.frame, xy, theta, w * same, 0.3,
                                          0.9, tu, tv), abs=1e-6)
    if part.density.shape == whole.density.shape:
        return                                # the whole image: restricted as any
    with pytest.raises(ValueError, match="region only"):
        restrict_maps(part, np.array([u0, v0], dtype=float), np.array([u1, v1], dtype=float))
    # The chance level is still the whole image's, from the points alone.
    assert part.chance == pytest.approx(whole.chance, rel=1e-6)
    assert len(part.vote_weight) == 0


def test_a_region_refuses_what_it_cannot_tabulate():
    feats = EdgeFeatures(xy=np.array([[10.0, 10.0]]), theta=np.array([0.3]))
    kw = {"position_sigma": 2.0, "orientation_kappa": 8.0, "region": (0, 0, 20, 20)}
    with pytest.raises(ValueError, match="density_cap"):
        prepare_test(feats, (40, 40), density_cap=0.5, **kw)
    with pytest.raises(ValueError, match="density_cap"):
        prepare_test(feats, (40, 40), **{**kw, "position_sigma": 9.0})
    with pytest.raises(ValueError, match="no pixel"):
        prepare_test(feats, (40, 40), **{**kw, "region": (50, 50, 60, 60)})


def test_a_region_of_a_huge_frame_is_tabulated_where_the_whole_frame_would_not_be():
    # A tiny scale's frame (the image divided by it) is too large to tabulate whole; a
    # region of it is not.
    feats = EdgeFeatures(xy=np.array([[30000.0, 20000.0]]), theta=np.array([0.3]))
    shape = (25000, 40000)
    kw = {"position_sigma": 2.0, "orientation_kappa": 8.0}
    with pytest.raises(ValueError, match="over the limit"):
        prepare_test(feats, shape, **kw)
    part = prepare_test(feats, shape, region=(29950, 19950, 30050, 20050), **kw)
    assert part.density.shape[1:] == (101, 101) and part.density.max() > 0

def _gaussian_sum(xy, shape, sigma):
    rows, cols = np.mgrid[0:shape[0], 0:shape[1]]
    return sum(np.exp(-((cols - u) ** 2 + (rows - v) ** 2) / (2 * sigma**2)) / (2 * np.pi * sigma**2)
               for u, v in xy)


@pytest.mark.parametrize("sigma", [2.0, 6.0, 10.9, 16.0])
def test_blurred_points_is_a_sum_of_gaussians(sigma):
    # Narrow kernels round the points to pixels (half a pixel off moves a
    # 2-px kernel by a fifth of its peak); wide ones go through the coarse
    # grid (two cells a sigma), within 8% of the peak.
    rng = np.random.default_rng(2)
    xy = rng.uniform((40, 40), (160, 110), (6, 2))
    k, *grid = map_grid(sigma, (150, 200))
    planes = blurred_points(xy, np.ones(len(xy)), (150, 200), sigma)
    assert planes.shape == tuple(grid)
    # Read at the pixels as the kernels read them.
    got = _refine(planes, k, (150, 200))
    want = _gaussian_sum(xy, (150, 200), sigma)
    assert got.dtype == np.float32 and got.shape == (150, 200)
    tolerance = 0.25 if sigma < 4 else 0.08
    assert np.abs(got - want).max() < tolerance * want.max()
    # The mass stays (nothing near the border is lost).
    assert got.sum() == pytest.approx(len(xy), rel=1e-3)


def test_from_four_pixels_the_blocks_beat_rounding_to_pixels():
    # A 4.4-px kernel (the cluttered preset's search) goes through 2-pixel
    # blocks, which read closer to the sum of Gaussians than the points
    # rounded to their pixels and blurred there.
    rng = np.random.default_rng(5)
    shape, sigma = (150, 200), 4.4
    xy = rng.uniform((40, 40), (160, 110), (40, 2))
    k = map_grid(sigma, shape)[0]
    assert k == 2
    got = _refine(blurred_points(xy, np.ones(len(xy)), shape, sigma), k, shape)
    plane = np.zeros(shape, dtype=np.float32)
    np.add.at(plane, (np.rint(xy[:, 1]).astype(int), np.rint(xy[:, 0]).astype(int)), 1.0)
    rounded = cv2.GaussianBlur(plane, (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
    want = _gaussian_sum(xy, shape, sigma)
    assert np.sqrt(np.mean((got - want) ** 2)) < np.sqrt(np.mean((rounded - want) ** 2))


@pytest.mark.parametrize("border", [cv2.BORDER_CONSTANT, cv2.BORDER_REFLECT])
def test_smooth_matches_gaussian_blur_on_a_smooth_plane(border):
    rng = np.random.default_rng(4)
    plane = cv2.GaussianBlur(rng.random((90, 130)).astype(np.float32), (0, 0), 4.0)
    for sigma in (2.0, 12.0, 30.0):
        want = cv2.GaussianBlur(plane, (0, 0), sigma, borderType=border)
        got = smooth(plane, sigma, border)
        assert got.shape == plane.shape
        # Away from the border, where the coarse grid's padding differs.
        inner = (slice(10, -10), slice(10, -10))
        assert np.abs(got - want)[inner].max() < 0.02 * np.abs(want).max()


def test_merged_voters_keep_the_votes():
    rng = np.random.default_rng(6)
    xy = np.vstack([np.stack([np.linspace(10, 90, 60), np.full(60, 40.0)], 1),
                    rng.uniform(0, 100, (200, 2))])
    theta = np.concatenate([np.full(60, 0.05), rng.uniform(0, np.pi, 200)])
    feats = EdgeFeatures(xy=xy, theta=theta)
    vxy, vtheta, vw = merge_voters(feats, np.ones(len(theta)), 16, 4.0)
    # Fewer voters, sorted by orientation, the same total weight in every
    # orientation bin, and each at the mean of what it merged.
    assert len(vw) < len(theta) and vw.sum() == pytest.approx(len(theta))
    assert np.all(np.diff(vtheta) >= 0)
    bins = np.minimum((theta / np.pi * 16).astype(int), 15)
    voter_bins = np.minimum((vtheta / np.pi * 16).astype(int), 15)
    np.testing.assert_allclose(np.bincount(voter_bins, weights=vw, minlength=16),
                               np.bincount(bins, minlength=16))
    # The line's features merge three by three (4-px cells, 1.36 px apart)
    # but where a clutter feature of its bin falls in the same cell.
    line = np.flatnonzero(np.abs(vxy[:, 1] - 40.0) < 1e-9)
    assert vw[line].sum() >= 50 and np.all(vw[line] >= 2)
    assert np.all(np.abs(vtheta[line] - 0.05) < 1e-9)
    # The smoothed votes of the merged voters are those of the features.
    train_xy = np.stack([np.linspace(-30, 30, 25), np.zeros(25)], 1)
    train_theta, train_w = np.full(25, 0.05), np.full(25, 1 / 25)
    lut = np.where(np.arange(64) < 8, 1.0, 0.0)
    taps = blur_taps(1.5)

    def votes(points, angles, weight):
        acc = np.zeros((30, 30))
        accumulate_votes(train_xy, train_theta, train_w, 0.0, 1.0, points, angles, weight,
                         lut, 4.0, acc)
        return cv2.sepFilter2D(acc, -1, taps, taps)

    order = np.argsort(theta, kind="stable")
    full = votes(xy[order], theta[order], np.ones(len(theta)))
    merged = votes(vxy, vtheta, vw)
    assert np.unravel_index(full.argmax(), full.shape) == np.unravel_index(merged.argmax(),
                                                                             merged.shape)
    assert np.abs(full - merged).max() < 0.1 * full.max()


@pytest.mark.parametrize("shape", [(5, 4), (1, 1), (3, 40)])
def test_a_wide_kernel_on_a_tiny_image_keeps_its_grid_readable(shape):
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 1, (20, 2)) * [shape[1] - 1, shape[0] - 1]
    maps = prepare_test(EdgeFeatures(xy=xy, theta=rng.uniform(0, np.pi, 20)), shape,
                        position_sigma=9.5, orientation_kappa=8.0)
    # At least two cells each way, so that the bilinear reading never leaves the grid.
    assert maps.grid == map_grid(9.5, shape)[0] > 1 and min(maps.density.shape[1:]) >= 2
    assert np.isfinite(maps.chance) and maps.chance > 0
    # A window wholly outside the image reads nothing and has no chance level.
    away = restrict_maps(maps, np.array([50.0, 50.0]), np.array([60.0, 60.0]))
    assert away.chance == 0.0
    assert not density_at(away, xy, np.full(len(xy), 0.5)).any()


@pytest.mark.parametrize(("sigma", "shape"), [(3.0, (60, 70)), (7.0, (90, 110)), (11.0, (130, 97))])
def test_orientation_planes_agree_with_blurred_strengths(sigma, shape):
    # The compiled pass against the numpy reference: the strengths computed
    # by orientation_kernel, then blurred_points (narrow kernels at the
    # pixels, wide ones on the coarse grid); points on the border included.
    rng = np.random.default_rng(5)
    xy = np.vstack([rng.uniform(0, 1, (700, 2)) * (shape[1] - 1, shape[0] - 1),
                    [[0.0, 0.0], [shape[1] - 1.0, shape[0] - 1.0]]])
    theta = rng.uniform(0, np.pi, len(xy))
    weight = rng.uniform(0.5, 2.0, len(xy))
    centres = (np.arange(16) + 0.5) * np.pi / 16
    planes = orientation_planes(xy, theta, weight, centres, 3.0, shape, sigma)
    strength = weight[None, :] * orientation_kernel(theta[None, :] - centres[:, None], 3.0)
    reference = blurred_points(xy, strength, shape, sigma)
    assert planes.shape == reference.shape == (16, *map_grid(sigma, shape)[1:])
    np.testing.assert_allclose(planes, reference, rtol=1e-5, atol=1e-7 * reference.max())
