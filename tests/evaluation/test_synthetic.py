"""Views pasted on clutter, with their truth."""

import numpy as np

from posevote.evaluation import paste_on_clutter


def test_paste_on_clutter_truth(draw):
    img = draw(0.3)
    from posevote.data import object_box

    box = object_box(img)
    rng = np.random.default_rng(1)
    p = paste_on_clutter(img, box, rng=rng, occlusion=0.2)
    assert p.image.shape == (256, 256)
    assert 0.1 < p.occluded_fraction < 0.35
    assert 0.7 <= p.scale <= 1.3
    u, v = p.position
    x, y, w, h = p.box
    assert x <= u <= x + w and y <= v <= y + h


def test_clutter_search_covers_the_pasting_ranges():
    import inspect

    from posevote import PoseEstimator

    defaults = inspect.signature(paste_on_clutter).parameters
    search = PoseEstimator.from_preset("cluttered").search
    assert search.scale_range == defaults["scale_range"].default
    assert search.inplane_range_deg == defaults["inplane_range_deg"].default


def test_same_seed_same_image(draw):
    img = draw(0.3)
    box = np.array([30.0, 30.0, 60.0, 60.0])
    a = paste_on_clutter(img, box, rng=np.random.default_rng(5))
    b = paste_on_clutter(img, box, rng=np.random.default_rng(5))
    assert np.array_equal(a.image, b.image)
