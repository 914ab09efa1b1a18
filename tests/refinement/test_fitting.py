import numpy as np
import pytest

from posevote.geometry import angle_difference, viewing_direction
from posevote.inference.probes import ProbeSet
from posevote.refinement.fitting import find_modes, peak_viewpoint, refine_mode


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


def _fit_problem(turntable, view, inplane, scale, seed=0):
    """A fit's inputs: probes around (40 deg, 10 deg), scores from the model plus noise."""
    from posevote.refinement.fitting import _model

    rng = np.random.default_rng(seed)
    az, el = np.meshgrid(np.radians([20, 30, 40, 50, 60]),
                         np.radians([10.0]) if turntable else np.radians([0, 10, 20]))
    a, s = np.radians([-20.0, -10.0, 0.0, 10.0, 20.0]), np.log([0.8, 0.9, 1.0, 1.1, 1.2])
    vv, aa, ss = np.meshgrid(np.arange(az.size), np.arange(5), np.arange(5), indexing="ij")
    X = {"dir": viewing_direction(az.ravel(), el.ravel())[vv.ravel()],
         "inplane": a[aa.ravel()], "logs": s[ss.ravel()]}
    layout = {"view": view, "inplane": inplane, "scale": scale, "view_shape": 0.6,
              "fixed_elevation": np.radians(10.0) if turntable else None}
    truth, p0, lo, hi = [0.1, 0.8], [0.1, 0.5], [0.0, 0.0], [1.0, 4.0]
    if view:
        n = 2 if turntable else 3
        truth += ([np.radians(43.0)] + ([] if turntable else [np.radians(7.0)]) + [25.0])
        p0 += [np.radians(40.0)] + ([] if turntable else [np.radians(10.0)]) + [10.0]
        lo += [np.radians(30.0)] + ([] if turntable else [0.0]) + [1.0]
        hi += [np.radians(50.0)] + ([] if turntable else [np.radians(20.0)]) + [500.0]
        assert len(truth) == 2 + n
    if inplane:
        truth, p0 = truth + [0.03, 20.0], p0 + [0.0, 10.0]
        lo, hi = lo + [-0.17, 1.0], hi + [0.17, 500.0]
    if scale:
        truth, p0 = truth + [0.02, 0.08], p0 + [0.0, 0.1]
        lo, hi = lo + [-0.1, 0.005], hi + [0.1, 0.4]
    y = _model(np.array(truth), layout, X)[0] + rng.normal(0.0, 0.005, len(X["logs"]))
    return (np.array(p0), np.array(lo), np.array(hi), X, y, layout), np.array(truth)


LAYOUTS = [(t, v, a, s) for t in (True, False) for v in (True, False) for a in (True, False)
           for s in (True, False) if v or a or s]


@pytest.mark.parametrize("turntable,view,inplane,scale", LAYOUTS)
def test_compiled_model_matches_the_reference(turntable, view, inplane, scale):
    from posevote.refinement.fitting import _model, _model_kernel

    (p0, lo, hi, X, y, layout), truth = _fit_problem(turntable, view, inplane, scale)
    params = 0.5 * (truth + p0)
    f, jac = _model(params, layout, X)
    f2, jac2 = np.empty_like(f), np.empty_like(jac)
    _model_kernel(params, X["dir"], X["inplane"], X["logs"], view, inplane, scale,
                  np.nan if turntable is False else np.radians(10.0), 0.6, f2, jac2)
    np.testing.assert_allclose(f2, f, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(jac2, jac, rtol=1e-10, atol=1e-12)
    # and the Jacobian is the model's own derivative
    eps = 1e-6
    numeric = np.stack([(_model(params + eps * e, layout, X)[0]
                         - _model(params - eps * e, layout, X)[0]) / (2 * eps)
                        for e in np.eye(len(params))], axis=1)
    np.testing.assert_allclose(jac, numeric, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("turntable,view,inplane,scale", LAYOUTS)
def test_compiled_fit_agrees_with_scipy(turntable, view, inplane, scale):
    from posevote.refinement.fitting import solve_fit, solve_fit_reference

    problem, truth = _fit_problem(turntable, view, inplane, scale)
    fast, ref = solve_fit(*problem, 1e-8), solve_fit_reference(*problem, 1e-8)
    means = [2, 3] if view and not turntable else [2] if view else []
    means += [len(truth) - 2 - 2 * scale] if inplane else []
    means += [len(truth) - 2] if scale else []
    # The means (what the estimate reads) agree to a hundredth of a degree.
    np.testing.assert_allclose(fast[means], ref[means], atol=2e-4)
    np.testing.assert_allclose(fast[means], truth[means], atol=0.02)


def test_compiled_fit_stays_inside_its_bounds():
    from posevote.refinement.fitting import solve_fit

    (p0, lo, hi, X, y, layout), truth = _fit_problem(True, True, True, True)
    hi[2] = np.radians(41.0)  # the truth (43 degrees) is past the bound
    p = solve_fit(p0, lo, hi, X, y, layout, 1e-8)
    assert np.all(p >= lo) and np.all(p <= hi)
    assert p[2] == pytest.approx(hi[2], abs=1e-4)


def test_compiled_fit_refuses_non_finite_scores():
    from posevote.refinement.fitting import solve_fit, solve_fit_reference

    (p0, lo, hi, X, y, layout), _ = _fit_problem(True, True, True, True)
    y[3] = np.nan
    assert solve_fit(p0, lo, hi, X, y, layout, 1e-4) is None
    assert solve_fit_reference(p0, lo, hi, X, y, layout, 1e-4) is None


def sphere_profile(mu_az, mu_el, elevations=None):
    """A local refinement's profile over the sphere's training grid (one score a view),
    falling off as a Gaussian of 8 degrees in the angle from a viewpoint between the views."""
    elevations = np.arange(-30, 61, 7.5) if elevations is None else elevations
    width = np.radians(8.0)
    az, el = (np.radians(a).ravel() for a in np.meshgrid(np.arange(0, 360, 10.0), elevations))
    angle = np.arccos(np.clip(viewing_direction(az, el) @ viewing_direction(mu_az, mu_el), -1, 1))
    score = 0.1 + 0.8 * np.exp(-angle**2 / (2 * width**2))
    return ProbeSet(azimuth=az, elevation=el, inplane=np.zeros(1), scale=np.ones(1),
                    score=score[:, None, None], translation=np.zeros((len(az), 1, 1, 2)),
                    box=np.full((len(az), 2), 30.0))


@pytest.mark.parametrize("truth", [(43.0, 11.0), (357.0, -26.0), (121.0, 49.0)])
def test_peak_viewpoint_reads_the_peak_between_views(truth):
    probes = sphere_profile(*np.radians(truth))
    az, el = peak_viewpoint(probes, int(np.argmax(probes.score[:, 0, 0])))
    assert abs(angle_difference(np.degrees(az), truth[0], period=360.0)) < 1.0
    assert np.degrees(el) == pytest.approx(truth[1], abs=1.0)


def test_peak_viewpoint_needs_a_concave_profile_over_several_elevations():
    probes = sphere_profile(np.radians(43.0), np.radians(11.0))
    best = int(np.argmax(probes.score[:, 0, 0]))
    valley = ProbeSet(**{**probes.__dict__, "score": -probes.score})
    assert peak_viewpoint(valley, int(np.argmin(probes.score[:, 0, 0]))) is None
    ring = sphere_profile(np.radians(43.0), 0.0, elevations=np.zeros(1))
    assert peak_viewpoint(ring, int(np.argmax(ring.score[:, 0, 0]))) is None
    assert peak_viewpoint(probes, best) is not None
