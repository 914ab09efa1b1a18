"""Mode probabilities from the score profile over viewpoints."""

import numpy as np
import pytest

from posevote.geometry import viewing_direction
from posevote.inference.probes import ProbeSet
from posevote.inference.setup import SearchOptions
from posevote.refinement.probability import (
    IDENTITY,
    MODE_RADIUS,
    calibrated,
    mode_probabilities,
    scored_viewpoints,
    with_probabilities,
)
from posevote.results import Hypothesis


def _probes(*peaks):
    """Probes on a 20-degree turntable grid with a peak of height h at each (azimuth, h)."""
    az = np.radians(np.arange(0, 360, 20.0))
    score = np.full(len(az), 0.1)
    for mu, h in peaks:
        d = viewing_direction(az, 0.0) @ viewing_direction(np.radians(mu), 0.0)
        score = score + h * np.exp(12.0 * (d - 1))
    score = np.broadcast_to(score[:, None, None], (len(az), 3, 2)).copy()
    return ProbeSet(azimuth=az, elevation=np.zeros_like(az), inplane=np.zeros(3),
                    scale=np.ones(2), score=score, translation=np.zeros(score.shape + (2,)),
                    box=np.full((len(az), 2), 30.0))

AZ = np.radians(np.arange(0, 360, 10.0))
DIRS = viewing_direction(AZ, np.zeros_like(AZ))


def _modes(*deg):
    a = np.radians(np.array(deg, dtype=float))
    return viewing_direction(a, np.zeros_like(a))


def test_one_sharp_peak_is_nearly_certain():
    profile = np.where(np.abs(AZ - np.radians(90)) < 0.01, 1.0, 0.2)
    p = mode_probabilities(DIRS, profile, _modes(90.0), sharpness=12.0)
    assert p[0] > 0.99


def test_two_equal_peaks_share_and_a_flat_profile_gives_the_radius_share():
    two = np.where(np.isin(np.round(np.degrees(AZ)), [0, 180]), 1.0, 0.1)
    p = mode_probabilities(DIRS, two, _modes(0.0, 180.0))
    assert p == pytest.approx([0.5, 0.5], abs=1e-3)
    flat = np.ones(len(AZ))
    p = mode_probabilities(DIRS, flat, _modes(0.0))
    # 30 degrees either side of the mode on a 10-degree grid: 7 of the 36 viewpoints
    assert p[0] == pytest.approx(7 / 36)
    assert 2 * np.degrees(MODE_RADIUS) / 360 < p[0] < 0.25


def test_probabilities_are_bounded_and_sum_to_at_most_one():
    rng = np.random.default_rng(0)
    for _ in range(20):
        profile = rng.random(len(AZ))
        p = mode_probabilities(DIRS, profile, _modes(*rng.uniform(0, 360, 3)),
                               sharpness=float(rng.uniform(0, 30)))
        assert np.all((p >= 0) & (p <= 1)) and p.sum() <= 1 + 1e-12
    # a sharper posterior trusts the top of the profile more
    profile = np.where(np.isin(np.round(np.degrees(AZ)), [0]), 1.0, 0.8)
    soft, sharp = (mode_probabilities(DIRS, profile, _modes(0.0), sharpness=k)[0] for k in (1, 30))
    assert sharp > soft


def test_degenerate_input():
    assert mode_probabilities(DIRS, np.zeros(len(AZ)), _modes(0.0)).tolist() == [0.0]
    assert mode_probabilities(DIRS, np.ones(len(AZ)), np.zeros((0, 3))).shape == (0,)
    with pytest.raises(ValueError, match="profile has 3 values for 36 directions"):
        mode_probabilities(DIRS, np.ones(3), _modes(0.0))


def _two_modes():
    """Probes with peaks at 40 and 220 degrees, and a mode at each (the first the better)."""
    probes = _probes((40.0, 0.8), (220.0, 0.4))
    hyps = [Hypothesis(azimuth=np.radians(a), elevation=0.0, inplane=0.0, scale=1.0,
                       position=(0.0, 0.0), box=(0, 0, 1, 1), score=s, refined=True)
            for a, s in ((40.0, 0.9), (220.0, 0.5))]
    return probes, hyps


def test_with_probabilities_sets_each_mode_and_keeps_the_pose():
    probes, hyps = _two_modes()
    out = with_probabilities(hyps, probes)
    assert out[0].azimuth == hyps[0].azimuth and out[0].probability > out[1].probability > 0
    assert np.isnan(hyps[0].probability)
    assert out[0].to_dict()["probability"] == out[0].probability
    assert with_probabilities([], probes) == []
    scored = scored_viewpoints(probes)
    assert len(scored) == len(probes.azimuth) and scored[0][0] == probes.azimuth[0]


def test_calibrated_is_the_logistic_of_share_and_score():
    share, score = np.array([0.2, 0.5, 0.9]), np.array([0.1, 0.3, 0.6])
    assert calibrated(share, score, IDENTITY).tolist() == share.tolist()
    a, b, c = 0.8, 2.0, 1.5
    z = a * np.log(share / (1 - share)) + b * np.log(score) + c
    assert np.allclose(calibrated(share, score, (a, b, c)), 1 / (1 + np.exp(-z)))
    # A higher score never lowers it; a share of 0 or 1 and a score of 0 stay finite.
    assert np.all(np.diff(calibrated(0.5, [0.1, 0.2, 0.4], (a, b, c))) > 0)
    edge = calibrated([0.0, 1.0], [0.0, 1.0], (a, b, c))
    assert np.all(np.isfinite(edge)) and np.all((edge > 0) & (edge < 1))


def test_calibration_sets_the_best_mode_and_scales_the_others_to_what_is_left():
    probes, hyps = _two_modes()
    raw = with_probabilities(hyps, probes)
    sure = with_probabilities(hyps, probes, (1.0, 0.0, 5.0))
    assert sure[0].probability == pytest.approx(float(calibrated(raw[0].probability, 0.9,
                                                                 (1.0, 0.0, 5.0))))
    assert sure[0].probability + sure[1].probability <= 1.0 + 1e-12
    assert sure[1].probability < raw[1].probability
    # A low score takes the best mode's probability down whatever its share.
    doubt = with_probabilities(hyps, probes, (1.0, 4.0, 0.0))
    assert doubt[0].probability < raw[0].probability
    # Where the contrast is measured, the detection score it reads is the contrast.
    from dataclasses import replace

    measured = [replace(hyps[0], contrast=7.0), hyps[1]]
    read = with_probabilities(measured, probes, (1.0, 0.5, -1.0))
    assert read[0].probability == pytest.approx(float(calibrated(raw[0].probability, 7.0,
                                                                 (1.0, 0.5, -1.0))))


@pytest.mark.parametrize("bad", [(1.0, 0.0), (-0.5, 0.0, 0.0), (1.0, float("nan"), 0.0),
                                 (1.0, 0.0, 1e3), "abc"])
def test_search_options_refuse_a_malformed_calibration(bad):
    with pytest.raises(ValueError, match="SearchOptions.calibration must be"):
        SearchOptions(calibration=bad)
    assert SearchOptions(calibration=[0, 1, 2]).calibration == (0.0, 1.0, 2.0)
