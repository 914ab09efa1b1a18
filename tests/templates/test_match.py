import copy
from dataclasses import replace

import cv2
import numpy as np
import pytest

from posevote.results import Hypothesis
from posevote.templates import TemplateOptions
from posevote.templates import match as templates
from posevote.templates.match import (
    TILES,
    correlations,
    gradient_similarity,
    rerank_by_template,
    sample_bilinear,
    template_pixels,
    tile_correlation,
)
from posevote.templates.model import TEMPLATE_SIDE, template_frame


def _template(seed=0):
    rng = np.random.default_rng(seed)
    t = rng.random((TEMPLATE_SIDE, TEMPLATE_SIDE)).astype(np.float16)
    t[:4] = np.nan                                  # outside the mask
    return t


def test_tile_correlation_is_one_for_the_template_and_minus_one_inverted():
    t = _template()
    px = template_pixels(t)
    assert px.tile.max() == TILES * TILES - 1 and len(px.tile) == np.isfinite(t).sum()
    assert tile_correlation(px.value, px.value, px.tile) == pytest.approx(1.0)
    assert tile_correlation(1.0 - px.value, px.value, px.tile) == pytest.approx(-1.0)
    other = template_pixels(_template(1)).value
    assert abs(tile_correlation(other, px.value, px.tile)) < 0.1


def test_a_hidden_band_loses_only_its_own_tiles():
    px = template_pixels(_template())
    seen = px.value.copy()
    # A band over the left fifth of the template (under a quarter of the tiles) hidden by noise.
    band = px.xy[:, 0] < TEMPLATE_SIDE // 5
    seen[band] = np.random.default_rng(7).random(band.sum())
    assert tile_correlation(seen, px.value, px.tile) > 0.95


def test_an_empty_template_correlates_zero():
    px = template_pixels(np.full((TEMPLATE_SIDE, TEMPLATE_SIDE), np.nan, dtype=np.float16))
    assert len(px.tile) == 0
    assert tile_correlation(px.value, px.value, px.tile) == 0.0
    out = correlations(np.zeros((8, 8), np.float32),
                       template_frame(np.array([[4.0, 4.0]]), np.array([0.1]), np.zeros(1)),
                       np.zeros(1, np.int64), [px])
    assert out.tolist() == [0.0]


def test_bilinear_sampling_reads_pixels_and_extends_the_border():
    image = np.arange(12.0).reshape(3, 4)
    xy = np.array([[1.0, 2.0], [1.5, 0.5], [-3.0, 1.0], [9.0, 9.0]])
    np.testing.assert_allclose(sample_bilinear(image, xy), [9.0, 3.5, 4.0, 11.0])


def test_compiled_correlations_equal_the_numpy_reference():
    rng = np.random.default_rng(5)
    images = rng.random((2, 60, 80)).astype(np.float32)
    pixels = [template_pixels(_template(0)), template_pixels(_template(3))]
    n = 12
    # Some frames run past the image's border.
    frames = template_frame(rng.uniform(-10, 90, (n, 2)), rng.uniform(0.2, 1.2, n),
                            rng.uniform(-np.pi, np.pi, n))
    image_of, view_of = rng.integers(0, 2, n), rng.integers(0, 2, n)
    got = np.array([correlations(images[image_of[i]], frames[i:i + 1], view_of[i:i + 1],
                                 pixels)[0] for i in range(n)])
    for i in range(n):
        px = pixels[view_of[i]]
        xy = px.xy @ frames[i, :, :2].T + frames[i, :, 2]
        want = tile_correlation(sample_bilinear(images[image_of[i]], xy), px.value, px.tile)
        assert got[i] == pytest.approx(want, abs=1e-9)


def _copies(draw, azimuth, *, true_at, negative_at):
    """The object on grey where ``true_at`` says (0: left half, 1: right half, None: not
    drawn) and its negative (every grey level mirrored about the background's: the same
    edges, other grey levels) where ``negative_at`` says."""
    obj = draw(azimuth)
    drawn = np.where(obj > 0.02, obj, 0.5)
    canvas = np.full((128, 256), 0.5)
    for half, values in ((true_at, drawn), (negative_at, 1.0 - drawn)):
        if half is not None:
            canvas[:, 128 * half:128 * (half + 1)] = values
    return canvas


def _best_u(probes):
    v, a, k = np.unravel_index(np.argmax(probes.score), probes.score.shape)
    return probes.translation[v, a, k, 0]


def test_template_reranking_tells_the_object_from_its_negative(fitted_estimator,
                                                               synthetic_training, draw,
                                                               monkeypatch):
    from posevote import PoseEstimator

    est = PoseEstimator(search=fitted_estimator.search,
                        templates=TemplateOptions(half_turn=False)).fit(
        *synthetic_training[:2], boxes=synthetic_training[2])
    azimuth = np.radians(60)
    # The edges alone score the object and its negative alike.
    alone = fitted_estimator.probe(_copies(draw, azimuth, true_at=1, negative_at=None))[0]
    negative = fitted_estimator.probe(_copies(draw, azimuth, true_at=None, negative_at=1))[0]
    assert negative.score.max() == pytest.approx(alone.score.max(), rel=0.02)
    # Re-ranked, the object wins on either side.
    for true_at in (0, 1):
        image = _copies(draw, azimuth, true_at=true_at, negative_at=1 - true_at)
        ranked, _ = est.probe(image)
        assert (_best_u(ranked) > 128) == bool(true_at)
        assert (est.estimate(image).best.position[0] > 128) == bool(true_at)
    # The best probes, and those beyond them whose edge score beats the best product, are
    # scaled by their correlations, the rest by the lowest of them (fewer candidates than
    # this image's scored probes, so that there is a rest).
    few = 50
    monkeypatch.setattr(templates, "TEMPLATE_CANDIDATES", few)
    ranked, _ = est.probe(image)
    plain, _ = fitted_estimator.probe(image)
    before, after = plain.score.ravel(), ranked.score.ravel()
    order = np.argsort(-before, kind="stable")
    order = order[before[order] > 0]
    top, deeper = order[:few], order[few:]
    bar = after[top].max()
    contenders, rest = deeper[before[deeper] > bar], deeper[before[deeper] <= bar]
    looked = np.concatenate([top, contenders])
    factor = after[looked] / before[looked]
    assert np.all((factor > 0) & (factor <= 1.0 + 1e-9))
    assert rest.size > 0
    np.testing.assert_allclose(after[rest], before[rest] * factor.min())


def test_template_reranking_reaches_past_its_candidates_for_a_probe_that_could_win(
        fitted_estimator, synthetic_training, draw, monkeypatch):
    from posevote import PoseEstimator

    est = PoseEstimator(search=fitted_estimator.search,
                        templates=TemplateOptions(half_turn=False)).fit(
        *synthetic_training[:2], boxes=synthetic_training[2])
    # The side on which the negative's edges score best: the one candidate is the negative.
    images = [_copies(draw, np.radians(60), true_at=t, negative_at=1 - t) for t in (0, 1)]
    true_at = next(t for t, im in enumerate(images)
                   if (_best_u(fitted_estimator.probe(im)[0]) > 128) != bool(t))
    image = images[true_at]
    plain, _ = fitted_estimator.probe(image)
    monkeypatch.setattr(templates, "TEMPLATE_CANDIDATES", plain.score.size)
    every, _ = est.probe(image)
    # One candidate: the probes whose edges beat its product are looked at too, so that
    # the re-ranked best is the one a re-ranking of every probe finds.
    monkeypatch.setattr(templates, "TEMPLATE_CANDIDATES", 1)
    one, _ = est.probe(image)
    assert np.argmax(one.score) == np.argmax(every.score)
    assert (_best_u(one) > 128) == bool(true_at)
    scored = plain.score > 0
    factor = one.score[scored] / plain.score[scored]
    # More probes than the one candidate carry a correlation of their own.
    assert np.count_nonzero(~np.isclose(factor, factor.min())) >= 1


def test_a_model_not_fitted_for_templates_is_refused(fitted_estimator, draw):
    assert fitted_estimator.model_.view_template is None     # fitted without the re-ranking
    probes, _ = fitted_estimator.probe(draw(0.0))
    with pytest.raises(ValueError, match="the template steps need the views' templates, "
                                         "learnt when the model is fitted with them"):
        rerank_by_template(probes, fitted_estimator.model_, draw(0.0))
    with pytest.raises(ValueError, match="fit \\(or retrain\\) with templates=TemplateOptions"):
        copy.deepcopy(fitted_estimator).set_params(templates=TemplateOptions()).estimate(
            draw(0.0))


def _sides():
    """A face (a body with an eye) and its plain back, on masks of the same outline."""
    face = np.full((TEMPLATE_SIDE, TEMPLATE_SIDE), np.nan, dtype=np.float32)
    face[16:80, 24:72] = np.linspace(0.1, 0.5, 48)   # a shaded body
    face[16:40, 24:72] += 0.4                        # the head
    back = face.copy()
    face[22:32, 40:56] = 0.0                         # the eye
    return face, back


def _scene(template, pose):
    """A noisy image showing ``template`` under ``pose`` (cell 1)."""
    frame = template_frame(np.asarray(pose.position), pose.scale, pose.inplane)
    shape = (200, 200)
    warp = {"dsize": shape[::-1], "flags": cv2.INTER_LINEAR}
    drawn = cv2.warpAffine(np.nan_to_num(template, nan=0.0), frame, **warp)
    mask = cv2.warpAffine(np.isfinite(template).astype(np.float32), frame, **warp)
    noise = np.random.default_rng(3).uniform(0.3, 0.7, shape).astype(np.float32)
    return mask * drawn + (1.0 - mask) * noise


def test_gradient_similarity_tells_a_face_from_its_plain_back():
    from types import SimpleNamespace

    face, back = _sides()
    model = SimpleNamespace(view_template=np.stack([face, back]).astype(np.float16),
                            view_template_cell=np.ones(2), view_azimuth=np.array([0.0, np.pi]),
                            view_elevation=np.zeros(2))
    pose = Hypothesis(azimuth=0.0, elevation=0.0, inplane=0.3, scale=1.2, position=(100.0, 90.0),
                      box=(0.0, 0.0, 1.0, 1.0), score=1.0, refined=True)
    image = _scene(face, pose)
    right = gradient_similarity(model, image, pose)
    assert right > 0.8
    # The plain back under the same pose misses the eye.
    assert gradient_similarity(model, image, replace(pose, azimuth=np.pi)) < right - 0.02
    # Where the face is not, the likeness falls.
    assert gradient_similarity(model, image, replace(pose, position=(30.0, 30.0))) < 0.5
    no_templates = SimpleNamespace(view_template=None, view_template_cell=None)
    with pytest.raises(ValueError, match="needs the views' templates"):
        gradient_similarity(no_templates, image, pose)
