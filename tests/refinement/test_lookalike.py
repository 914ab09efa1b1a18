"""How alike each view is to the object's other sides: measured at training, read by the
estimate's ``ambiguous``."""

from __future__ import annotations

import numpy as np
import pytest

from posevote import PoseEstimator
from posevote.data import read_coil
from posevote.refinement.lookalike import view_lookalikes
from posevote.results import LOOKALIKE


def _circle(radius, n=60):
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([radius * np.cos(t), radius * np.sin(t)]), np.mod(t + np.pi / 2, np.pi)


def _bar(angle, n=30):
    s = np.linspace(-20.0, 20.0, n)
    return np.column_stack([s * np.cos(angle), s * np.sin(angle)]), np.full(n, angle % np.pi)


def _model(shapes, azimuths_deg, instances=None):
    xy = np.vstack([s[0] for s in shapes])
    theta = np.concatenate([s[1] for s in shapes])
    view = np.concatenate([np.full(len(s[0]), k) for k, s in enumerate(shapes)])
    k = len(shapes)
    return dict(xy=xy, theta=theta, view=view, azimuth=np.radians(azimuths_deg),
                elevation=np.zeros(k),
                instance=np.zeros(k, dtype=int) if instances is None else np.array(instances))


def test_a_view_like_another_side_scores_near_one_and_one_unlike_near_zero():
    # A ring seen from four sides; a bar that turns with the azimuth.
    ring = view_lookalikes(**_model([_circle(20.0)] * 4, [0, 90, 180, 270]), position_sigma=3.0)
    bar = view_lookalikes(**_model([_bar(np.radians(a)) for a in (0, 90, 45, 135)],
                                   [0, 90, 180, 270]), position_sigma=3.0)
    assert np.all(ring > 0.95) and np.all(bar < 0.3)
    # A bar seen from its back is the same bar: alike to the view half a turn away.
    back = view_lookalikes(**_model([_bar(0.0), _bar(np.pi / 2), _bar(0.0)], [0, 90, 180]),
                           position_sigma=3.0)
    assert back[0] > 0.95 and back[2] > 0.95 and back[1] < 0.3


def test_only_other_sides_of_the_same_instance_count():
    # Views 20 degrees apart are the same side; another instance's views are not its sides.
    near = view_lookalikes(**_model([_circle(20.0)] * 2, [0, 20]), position_sigma=3.0)
    other = view_lookalikes(**_model([_circle(20.0)] * 2, [0, 180], instances=[0, 1]),
                            position_sigma=3.0)
    np.testing.assert_array_equal(near, 0.0)
    np.testing.assert_array_equal(other, 0.0)


def test_many_views_are_compared_with_an_even_subset_of_them(monkeypatch):
    from posevote.refinement import lookalike

    shapes = [_bar(np.radians(a)) for a in (0, 90, 45, 135, 0, 90)]
    views = _model(shapes, [0, 60, 120, 180, 240, 300])
    every = view_lookalikes(**views, position_sigma=3.0)
    monkeypatch.setattr(lookalike, "MAX_SIDES", 3)      # views 0, 2 and 5 the sides
    some = view_lookalikes(**views, position_sigma=3.0)
    np.testing.assert_allclose(every, [1, 1, 0, 0, 1, 1], atol=0.05)
    # Each view finds its twin where the twin is among the sides (view 4 finds view 0, view
    # 1 view 5); view 0's twin (view 4) is not one.
    np.testing.assert_allclose(some, [0, 1, 0, 0, 1, 0], atol=0.05)


def test_a_ring_is_ambiguous_and_a_box_is_not(coil_dir):
    # COIL object 47 (a ring) looks alike from every side; object 1 (a box) does not.
    def estimate(obj):
        train = read_coil(coil_dir, objects=[obj], azimuths_deg=range(0, 360, 40))
        test = read_coil(coil_dir, objects=[obj], azimuths_deg=[100])
        est = PoseEstimator.from_preset("default").fit(train.load_images(), train.poses,
                                                       boxes=train.boxes)
        return est.model_.view_lookalike, est.estimate(test.load_images()[0])

    ring_views, ring = estimate(47)
    box_views, box = estimate(1)
    assert np.all(ring_views >= LOOKALIKE) and np.all(box_views < LOOKALIKE)
    assert ring.best.lookalike >= LOOKALIKE and ring.ambiguous
    assert box.best.lookalike == pytest.approx(float(np.median(box_views)), abs=0.2)
    assert not box.ambiguous
