import numpy as np
import pytest

from posevote.geometry import viewing_direction
from posevote.inference.search import ProbeSet
from posevote.refinement import find_modes, refine_mode


def synthetic_probes(mu_az, mu_alpha=0.05, mu_scale=1.04, second=None, cusp=False):
    """Probe scores of a von Mises-Fisher profile, or with ``cusp`` one linear in the angle."""
    az = np.radians(np.arange(0, 360, 20.0))
    alpha = np.radians(np.arange(-20, 21, 5.0))
    scale = np.geomspace(0.8, 1.25, 5)
    d = viewing_direction(az, 0.0) @ viewing_direction(mu_az, 0.0)
    view = -np.arccos(np.clip(d, -1, 1)) / np.radians(15.0) if cusp else 12.0 * (d - 1)
    score = 0.1 + 0.8 * np.exp(
        view[:, None, None] + 30 * (np.cos(alpha[None, :, None] - mu_alpha) - 1)
        - np.log(scale[None, None, :] / mu_scale) ** 2 / (2 * 0.1**2))
    if second is not None:
        d2 = viewing_direction(az, 0.0) @ viewing_direction(second, 0.0)
        score = score + 0.5 * np.exp(12.0 * (d2[:, None, None] - 1))
    return ProbeSet(azimuth=az, elevation=np.zeros_like(az), inplane=alpha, scale=scale,
                    score=score, translation=np.full(score.shape + (2,), 40.0),
                    box=np.full((len(az), 2), 30.0))


def test_fit_recovers_continuous_pose():
    probes = synthetic_probes(np.radians(47.0))
    modes = find_modes(probes)
    hyp = refine_mode(probes, modes[0], view_shape=1.0)  # the profile's own kernel
    assert hyp.refined
    assert hyp.azimuth_deg == pytest.approx(47.0, abs=0.5)
    assert hyp.inplane == pytest.approx(0.05, abs=0.01)
    assert hyp.scale == pytest.approx(1.04, abs=0.01)
    coarse = refine_mode(probes, modes[0], fit=False)
    assert not coarse.refined and coarse.azimuth_deg in (40.0, 60.0)


def test_unprobed_probes_are_left_out_of_the_fit():
    from dataclasses import replace

    probes = synthetic_probes(np.radians(47.0))
    # A ranking search: scales 0, 2, 4 everywhere, 1 and 3 only at 40 and 60 degrees.
    probed = np.zeros(probes.score.shape, dtype=bool)
    probed[:, :, ::2] = True
    probed[[2, 3], :, 1::2] = True
    ranked = replace(probes, score=np.where(probed, probes.score, 0.0), probed=probed)
    mode = find_modes(ranked)[0]
    hyp = refine_mode(ranked, mode, view_shape=1.0)
    full = refine_mode(probes, mode, view_shape=1.0)
    assert hyp.azimuth_deg == pytest.approx(full.azimuth_deg, abs=0.01)
    assert hyp.azimuth_deg == pytest.approx(47.0, abs=0.01)
    assert hyp.scale == pytest.approx(1.04, abs=0.001)
    # Read as scores, the zeros pull the fit off (here by over a degree).
    unmarked = refine_mode(replace(ranked, probed=None), mode, view_shape=1.0)
    assert abs(unmarked.azimuth_deg - 47.0) > 1.0


@pytest.mark.parametrize("truth", [45.0, 55.0])
def test_sharp_profile_is_not_pulled_toward_the_probes(truth):
    # A profile linear in the angle, 5 degrees from a probed viewpoint: the
    # rounded von Mises-Fisher kernel pulls the mean toward that probe, the
    # default sharper kernel does not.
    probes = synthetic_probes(np.radians(truth), cusp=True)
    v = find_modes(probes)[0]
    rounded = refine_mode(probes, v, view_shape=1.0).azimuth_deg
    sharp = refine_mode(probes, v).azimuth_deg
    nearest = 40.0 if truth < 50 else 60.0
    assert abs(rounded - truth) > 1.0 and abs(rounded - nearest) < abs(truth - nearest)
    assert sharp == pytest.approx(truth, abs=0.7)


def test_second_mode_is_kept():
    probes = synthetic_probes(np.radians(40.0), second=np.radians(220.0))
    modes = find_modes(probes)
    assert len(modes) >= 2
    assert abs(np.degrees(probes.azimuth[modes[1]]) - 220) <= 20


def test_no_modes_on_empty_scores():
    probes = synthetic_probes(0.0)
    empty = ProbeSet(**{**probes.__dict__, "score": np.zeros_like(probes.score)})
    assert find_modes(empty) == []
