from dataclasses import replace

import numpy as np
import pytest

from posevote.features.edges import EdgeFeatures, extract_edges
from posevote.inference.coverage import COVERAGE_CANDIDATES, coverage, rerank_by_coverage
from posevote.inference.search import probe
from posevote.inference.setup import SearchOptions, search_maps
from posevote.scoring.maps import prepare_test


def _outline(points, step=2.0):
    """Edge points every ``step`` px along a closed polygon, with their tangents."""
    xy, theta = [], []
    for a, b in zip(points, np.roll(points, -1, axis=0), strict=True):
        n = max(int(np.linalg.norm(b - a) / step), 1)
        t = np.arange(n)[:, None] / n
        xy.append(a + t * (b - a))
        theta.append(np.full(n, np.mod(np.arctan2(*(b - a)[::-1]), np.pi)))
    return np.concatenate(xy), np.concatenate(theta)


# An "L": no half-turn of it lies on itself.
_L = np.array([[-30.0, -30.0], [-10.0, -30.0], [-10.0, 10.0], [30.0, 10.0], [30.0, 30.0],
               [-30.0, 30.0]])


def _maps(xy, theta, shape=(160, 160)):
    return prepare_test(EdgeFeatures(xy=xy, theta=theta), shape, position_sigma=2.0,
                        orientation_kappa=4.0)


def test_coverage_is_the_share_of_the_box_edges_the_model_explains():
    model_xy, model_theta = _outline(_L)
    centre = np.array([80.0, 80.0])
    box = np.array([60.0, 60.0])
    maps = _maps(model_xy + centre, model_theta)
    right = coverage(model_xy + centre, model_theta, maps, box, centre, edge_spacing=2.0)
    assert right > 0.9
    turned = coverage(-model_xy + centre, model_theta, maps, box, centre, edge_spacing=2.0)
    elsewhere = coverage(model_xy + centre + 200.0, model_theta, maps, box, centre,
                         edge_spacing=2.0)
    assert turned < right - 0.15 and elsewhere == 0.0
    # Edges in the box that the model does not have lower it in proportion.
    extra_xy, extra_theta = _outline(np.array([[-20.0, 15.0], [20.0, 15.0], [20.0, 25.0],
                                               [-20.0, 25.0]]))
    cluttered = _maps(np.concatenate([model_xy, extra_xy]) + centre,
                      np.concatenate([model_theta, extra_theta]))
    share = len(model_xy) / (len(model_xy) + len(extra_xy))
    assert coverage(model_xy + centre, model_theta, cluttered, box, centre,
                    edge_spacing=2.0) == pytest.approx(share, abs=0.12)
    # Too few edges in the box: nothing is explained.
    assert coverage(model_xy + centre, model_theta, _maps(model_xy[:3] + centre,
                                                          model_theta[:3]), box, centre,
                    edge_spacing=2.0) == 0.0


def test_rerank_multiplies_the_best_probes_and_keeps_the_order_of_the_rest(fitted_estimator,
                                                                           draw):
    est = fitted_estimator
    image = draw(np.radians(100))
    feats = extract_edges(image, est.edges, training=False)
    options = SearchOptions(scale_range=(0.9, 1.1), scale_steps=2, object_kernel=True,
                            rerank="coverage")
    setup = replace(est.setup(), options=options)
    maps = search_maps(feats, image.shape, est.model_, setup)
    probes = probe(est.model_, maps, setup)
    ranked = rerank_by_coverage(probes, est.model_, maps, setup)
    before, after = probes.score.ravel(), ranked.score.ravel()
    order = np.argsort(-before, kind="stable")
    top, rest = order[:COVERAGE_CANDIDATES], order[COVERAGE_CANDIDATES:]
    factor = after[top] / before[top]
    assert np.all((factor > 0) & (factor <= 1.0 + 1e-12))
    positive = rest[before[rest] > 0]
    # Every other probe is scaled by the lowest factor of the best ones.
    assert np.allclose(after[positive], before[positive] * factor.min())
    # The object is still found near its pose.
    best = np.unravel_index(np.argmax(ranked.score), ranked.score.shape)
    assert abs(np.degrees(ranked.azimuth[best[0]]) - 100) <= 20


def test_rerank_option_names_a_reranking():
    with pytest.raises(ValueError, match="rerank"):
        SearchOptions(rerank="yes")
    with pytest.raises(ValueError, match="rerank"):
        SearchOptions(rerank=True)
