from dataclasses import replace

import numpy as np
import pytest

from posevote.refinement import find_modes, polish_pose
from posevote.refinement.local import profile_refine


@pytest.fixture(scope="module")
def scene(fitted_estimator, draw):
    from posevote.data import object_box

    est = fitted_estimator
    img = draw(np.radians(60.0), scale=1.05, inplane=np.radians(4.0), centre=(66.0, 61.0))
    probes, _ = est.probe(img)
    feats, shape = est._features(img)
    fine = est._maps(feats, shape, sigma=est.position_sigma)
    x, y, w, h = object_box(img)
    return est, probes, fine, (x + (w - 1) / 2, y + (h - 1) / 2)


def test_polish_recovers_a_perturbed_pose(scene):
    est, probes, fine, _ = scene
    kw = dict(viewpoint_kappa=est.viewpoint_kappa_, k1_cutoff=est.k1_cutoff)
    from posevote.refinement import refine_mode

    start = refine_mode(probes, find_modes(probes)[0], fit=False)
    good = polish_pose(start, est.model_, fine, **kw)
    nudged = replace(good, position=(good.position[0] + 3.0, good.position[1] - 2.0),
                     scale=good.scale * 1.04)
    again = polish_pose(nudged, est.model_, fine, **kw)
    assert again.score == pytest.approx(good.score, abs=0.02)
    assert np.hypot(again.position[0] - good.position[0],
                    again.position[1] - good.position[1]) < 1.5
    assert again.scale == pytest.approx(good.scale, rel=0.02)


def test_profile_refine_lands_between_training_views(scene):
    est, probes, fine, centre = scene
    modes = find_modes(probes)
    hyp = profile_refine(probes, modes[0], est.model_, fine,
                         viewpoint_kappa=est.viewpoint_kappa_, k1_cutoff=est.k1_cutoff)
    assert hyp.refined
    assert abs(hyp.azimuth_deg - 60.0) < 10.0
    assert hyp.position == pytest.approx(centre, abs=3.0)
