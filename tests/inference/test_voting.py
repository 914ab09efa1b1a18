
import numpy as np
import pytest

from posevote.features import EdgeFeatures
from posevote.inference.voting import (
    POLISHED_STEPS,
    _argmax_nonnegative,
    _blur,
    accumulate_votes,
    accumulate_votes_reference,
    blur_reference,
    blur_taps,
    polish_translations,
    search_translations,
    strongest_voters,
)
from posevote.scoring.maps import prepare_test
from posevote.scoring.score import (
    gather_score,
)


@pytest.mark.parametrize("table", ["maps", "never zero"])
def test_votes_kernel_matches_reference(vote_scene, table):
    # The maps' table (the runs of orientations within reach, wrapping round
    # 0 and pi for the training voters near them) and one that never falls
    # to 0 (every pair, once).
    train_xy, train_theta, train_w, alpha, scale, _, maps = vote_scene
    lut = maps.lut if table == "maps" else 0.1 + maps.lut
    assert np.any(np.mod(train_theta + alpha, np.pi) < 0.1)
    assert np.any(np.mod(train_theta + alpha, np.pi) > np.pi - 0.1)
    acc = np.zeros((40, 50))
    accumulate_votes(train_xy, train_theta, train_w, alpha, scale, maps.vote_xy, maps.vote_theta,
                     maps.vote_weight, lut, 2.5, acc)
    ref = accumulate_votes_reference(train_xy, train_theta, train_w, alpha, scale, maps.vote_xy,
                                     maps.vote_theta, maps.vote_weight, lut, 2.5, (40, 50))
    assert acc.sum() > 0
    assert np.allclose(acc, ref, atol=1e-12)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize(("shape", "width"), [((51, 76), 1.5), ((7, 9), 2.0), ((40, 3), 0.8),
                                              ((5, 4), 2.0), ((1, 9), 3.3)])
def test_vote_blur_matches_reference(shape, width, dtype):
    # Double precision as numpy's sums; single, as the search blurs its votes.
    acc = np.random.default_rng(1).random(shape)
    taps = blur_taps(width)
    want = blur_reference(acc, taps)
    votes = acc.copy()
    acc = acc.astype(dtype)
    _blur(acc, acc, np.empty(shape, dtype=dtype), taps.astype(dtype))
    if dtype == np.float64:
        np.testing.assert_allclose(acc, want, rtol=1e-12, atol=1e-15)
    else:
        np.testing.assert_allclose(acc, want, rtol=1e-6, atol=1e-7)
    # From double-precision votes into another grid, as the search blurs them.
    out = np.full(shape, np.nan, dtype=dtype)
    _blur(votes, out, np.empty(shape, dtype=dtype), taps.astype(dtype))
    np.testing.assert_array_equal(out, acc)



@pytest.mark.parametrize("shape", [(126, 126), (7, 9), (1, 1)])
def test_the_vote_grids_argmax_is_numpys(shape):
    # Sparse grids with ties (the first of them wins), as blurred and suppressed votes are.
    rng = np.random.default_rng(4)
    for _ in range(50):
        grid = (rng.random(shape) * (rng.random(shape) < 0.4)).astype(np.float32)
        grid[rng.integers(shape[0]), : max(1, shape[1] // 3)] = grid.max()
        assert _argmax_nonnegative(grid) == np.argmax(grid)
    tiny = np.full(shape, np.float32(1e-40))  # subnormals order as integers too
    tiny.flat[-1] = np.float32(2e-40)
    assert _argmax_nonnegative(tiny) == np.argmax(tiny)
    assert _argmax_nonnegative(np.zeros(shape, dtype=np.float32)) == 0



def test_search_finds_the_translation(vote_scene):
    train_xy, train_theta, train_w, alpha, scale, t, maps = vote_scene
    score, trans = search_translations(maps, train_xy, train_theta, train_w,
                                       inplanes=np.array([0.0, alpha, 0.4]),
                                       scales=np.array([1.0, scale]))
    a, s = np.unravel_index(np.argmax(score), score.shape)
    assert (a, s) == (1, 1)
    assert trans[1, 1] == pytest.approx(t, abs=0.5)
    # Isolated points (not edges sampled every 2 px) each explain
    # spacing / (sqrt(2 pi) sigma) of a contour's density.
    assert score[1, 1] == pytest.approx(2.0 / (np.sqrt(2 * np.pi) * 2.0), abs=0.04)


def test_search_on_a_feature_subset(vote_scene):
    train_xy, train_theta, train_w, alpha, scale, t, maps = vote_scene
    grid = {"inplanes": np.array([0.0, alpha, 0.4]), "scales": np.array([1.0, scale])}
    full = search_translations(maps, train_xy, train_theta, train_w, **grid)
    same = search_translations(maps, train_xy, train_theta, train_w, max_features=40, **grid)
    assert np.array_equal(full[0], same[0]) and np.array_equal(full[1], same[1])
    # Every second feature, weights scaled to the same total: same pose, and
    # the score is still the weighted fraction explained.
    score, trans = search_translations(maps, train_xy, train_theta, train_w, max_features=20,
                                       **grid)
    assert np.unravel_index(np.argmax(score), score.shape) == (1, 1)
    assert trans[1, 1] == pytest.approx(t, abs=0.5)
    assert score[1, 1] == pytest.approx(full[0][1, 1], rel=0.1)
    ref = gather_score(maps.density, maps.frame, train_xy[::2], train_theta[::2],
                       train_w[::2] / train_w[::2].sum(), alpha, scale, *trans[1, 1])
    # (the search's peak value is interpolated between pixels, hence rel 1e-2)
    assert score[1, 1] == pytest.approx(ref, rel=1e-2)


def test_search_polishes_the_vote_peak_with_the_best_exact_score(vote_scene):
    # A decoy made of the voting features only (the 20 heaviest of 40, with
    # max_voters=20), each three times over, outvotes the object, but
    # with the density capped at one point's peak it explains only the
    # voters' share of the weight. Ranking the vote peaks by their exact
    # score finds the object; the top vote peak alone is the decoy.
    train_xy, train_theta, train_w, *_ = vote_scene
    obj, decoy = np.array([45.0, 50.0]), np.array([125.0, 50.0])
    voters = strongest_voters(train_w, 20)
    xy = np.vstack([train_xy + obj] + [train_xy[voters] + decoy] * 3)
    theta = np.concatenate([train_theta] + [train_theta[voters]] * 3)
    peak = 2.0 / (np.sqrt(2 * np.pi) * 2.0)
    maps = prepare_test(EdgeFeatures(xy=xy, theta=theta), (100, 170), position_sigma=2.0,
                        orientation_kappa=8.0, density_cap=peak)
    grid = {"inplanes": np.zeros(1), "scales": np.ones(1), "max_voters": 20}
    score, trans = search_translations(maps, train_xy, train_theta, train_w, n_candidates=3,
                                       **grid)
    assert trans[0, 0] == pytest.approx(obj, abs=0.5)
    top_score, top = search_translations(maps, train_xy, train_theta, train_w, n_candidates=1,
                                         **grid)
    assert np.linalg.norm(top[0, 0] - decoy) < 3.0   # on the decoy's capped plateau
    assert top_score[0, 0] < 0.8 * score[0, 0]


def test_an_unpolished_search_keeps_the_exact_score_at_the_vote_cell(vote_scene):
    train_xy, train_theta, train_w, alpha, scale, t, maps = vote_scene
    grid = {"inplanes": np.array([0.0, alpha, 0.4]), "scales": np.array([1.0, scale]),
            "cell": 2.5}
    polished = search_translations(maps, train_xy, train_theta, train_w, **grid)
    score, trans = search_translations(maps, train_xy, train_theta, train_w, polish=False, **grid)
    assert np.unravel_index(np.argmax(score), score.shape) == (1, 1)
    # On the vote lattice, within a cell of the peak, scored there exactly.
    assert np.allclose(trans / 2.5, np.round(trans / 2.5))
    assert np.all(np.abs(trans[1, 1] - t) <= 2.5)
    assert score[1, 1] == pytest.approx(gather_score(maps.density, maps.frame, train_xy,
                                                     train_theta, train_w, alpha, scale,
                                                     *trans[1, 1]), rel=1e-9)
    # The polish climbs from there to the peak.
    assert 0.8 * polished[0][1, 1] < score[1, 1] <= polished[0][1, 1]


def test_the_voters_are_the_heaviest_features_in_their_order():
    w = np.array([0.1, 0.5, 0.2, 0.9, 0.05, 0.5])
    assert strongest_voters(w, 3).tolist() == [1, 3, 5]
    assert strongest_voters(w, 1).tolist() == [3]
    assert strongest_voters(w, None).tolist() == strongest_voters(w, 6).tolist() == list(range(6))
    assert strongest_voters(w, 10).tolist() == list(range(6))




def test_only_the_best_steps_are_polished(vote_scene):
    # Thirteen in-plane angles in one call: the POLISHED_STEPS whose exact
    # score at the vote cell is best are polished as in a call of their own,
    # the others keep the unpolished score and cell.
    train_xy, train_theta, train_w, alpha, scale, _, maps = vote_scene
    angles = alpha + np.radians(np.arange(-30, 31, 5))
    kw = {"scales": np.array([scale]), "n_candidates": 2}
    rough, rough_t = search_translations(maps, train_xy, train_theta, train_w, inplanes=angles,
                                         polish=False, **kw)
    score, trans = search_translations(maps, train_xy, train_theta, train_w, inplanes=angles, **kw)
    best = np.argsort(-rough[:, 0], kind="stable")[:POLISHED_STEPS]
    rest = np.setdiff1d(np.arange(len(angles)), best)
    assert len(angles) > POLISHED_STEPS and 6 in best
    np.testing.assert_array_equal(score[rest], rough[rest])
    np.testing.assert_array_equal(trans[rest], rough_t[rest])
    for k in best:
        alone, alone_t = search_translations(maps, train_xy, train_theta, train_w,
                                             inplanes=angles[k:k + 1], **kw)
        assert score[k, 0] == alone[0, 0] >= rough[k, 0]
        np.testing.assert_array_equal(trans[k], alone_t[0])


def test_polishing_later_is_polishing_in_the_search(vote_scene):
    # An unpolished search polished afterwards from its vote cells gives what
    # the polished search gives, to the bit (four steps, fewer than
    # POLISHED_STEPS: the search polishes every one).
    train_xy, train_theta, train_w, alpha, scale, _, maps = vote_scene
    kw = {"inplanes": alpha + np.radians([-10.0, 0.0]), "scales": np.array([0.9, scale]),
          "n_candidates": 2}
    assert 4 <= POLISHED_STEPS
    rough, rough_t = search_translations(maps, train_xy, train_theta, train_w, polish=False, **kw)
    fine, fine_t = search_translations(maps, train_xy, train_theta, train_w, **kw)
    later, later_t = polish_translations(maps, train_xy, train_theta, train_w,
                                         inplanes=kw["inplanes"], scales=kw["scales"],
                                         score=rough, translation=rough_t)
    assert not np.array_equal(fine, rough)
    np.testing.assert_array_equal(later, fine)
    np.testing.assert_array_equal(later_t, fine_t)


@pytest.mark.parametrize("offset", [(6.0, -5.0), (-3.0, 7.0), (1.0, 0.0)])
def test_the_polish_climbs_to_the_peak_from_pixels_away(vote_scene, offset):
    # From a start several pixels off (odd and even offsets: the climb
    # strides 2 pixels, then steps 1), the polish ends on the exact score's
    # peak, above the score at the start and at the peak's pixel neighbours.
    train_xy, train_theta, train_w, alpha, scale, t, maps = vote_scene
    kw = {"inplanes": np.array([alpha]), "scales": np.array([scale])}
    start = np.array([[t + np.array(offset)]])
    score, trans = polish_translations(maps, train_xy, train_theta, train_w, score=np.ones((1, 1)),
                                       translation=start, **kw)
    assert trans[0, 0] == pytest.approx(t, abs=0.5)

    def exact(u, v):
        return gather_score(maps.density, maps.frame, train_xy, train_theta, train_w, alpha,
                            scale, u, v)

    assert score[0, 0] > exact(*start[0, 0])
    peak = np.floor(trans[0, 0] + 0.5)
    for du, dv in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        assert score[0, 0] >= exact(peak[0] + du, peak[1] + dv)
