import numpy as np

from posevote.inference import viewpoint_grid


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
