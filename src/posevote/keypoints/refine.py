"""The best mode's side and its viewpoint between the training views, from keypoints.

The test image's SIFT keypoints around the best mode's box, taken into the
features' frame by the mode's own position, scale and in-plane angle, are
matched to each training view's (Lowe's ratio test) and kept where a
similarity fitted by RANSAC takes them onto the view's: a view's inliers are
the texture's evidence for it. Where a view far from the estimate holds
clearly more of that evidence than the views near it, the estimate turns to
that view (a printed side is not its mirror). Then the viewpoint is read
between the best view and its neighbour of most inliers: the keypoints seen
in the test image and both views move, from one view to the other, along the
motions the two views give them, and how far they have moved says where the
test view lies between them (:func:`share_between`).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from posevote.features.edges import area_budget
from posevote.geometry import angle_difference, box_iou, rotate_points, viewing_direction
from posevote.inference.setup import SCALE_LIMITS
from posevote.keypoints.model import DESCRIPTOR_LENGTH, detect_keypoints
from posevote.model.density import PoseModel
from posevote.model.morph import view_neighbours
from posevote.refinement.fitting import box_from_pose
from posevote.results import Hypothesis

#: Lowe's ratio: a test keypoint's nearest descriptor in a view is a match when it is nearer
#: than this share of the second nearest.
MATCH_RATIO = 0.8
#: RANSAC's tolerance for the similarity onto a view, a share of its box's diagonal.
INLIER_SHARE = 0.025
#: The fewest inliers that speak for a view.
MIN_INLIERS = 8
#: A view this far from the estimate turns it when it holds this many times the inliers of
#: the views within NEAR_ANGLE of it.
TURN_ANGLE = math.radians(45.0)
NEAR_ANGLE = math.radians(30.0)
TURN_RATIO = 1.5
#: The whole image's keypoints place the object elsewhere when its view holds this many
#: times the inliers of any view in the mode's box.
LOCATE_RATIO = 2.0
#: The fewest keypoints seen in the test image and both views that read the viewpoint
#: between them.
MIN_SHARED = 4
#: The fit of the share between two views drops the keypoints off by more than this many
#: times the median residual (and this many reference pixels), this many times.
TRIM_SPREAD = 2.5
TRIM_FLOOR = 2.0
TRIM_ROUNDS = 3
#: The test keypoints are those within this share of the box's width and height from its
#: centre.
SEARCH_SHARE = 0.55
#: The most keypoints of a whole 640 x 480 test image that look for the object (SIFT's
#: strongest); as many per its area in a larger one (a cap per image lost a small object's
#: keypoints to a 1280 x 720 frame's clutter: docs/history/KEYPOINTS.md).
LOCATE_KEYPOINTS = 2000
#: The similarity onto a view may scale the mode's frame by this factor at most, either way,
#: and turn it by this angle at most: the mode has placed the object already.
MAX_SCALE = 1.5
MAX_TURN = math.radians(30.0)


def test_keypoints(image: NDArray[np.floating], hypothesis: Hypothesis, *,
                   upright: bool = False) -> tuple[NDArray[np.float64], NDArray[np.uint8]]:
    """The image's keypoints around the hypothesis's box, in the features' frame (from its
    position, upright, in reference pixels: its scale and in-plane angle undone; ``upright``:
    the object is upright, whatever in-plane angle a refinement gave the mode)."""
    x, y, w, h = hypothesis.box
    cu, cv = x + w / 2.0, y + h / 2.0
    half_u, half_v = SEARCH_SHARE * max(w, 1.0), SEARCH_SHARE * max(h, 1.0)
    rows, cols = image.shape[:2]
    u0, u1 = max(0, int(cu - half_u)), min(cols, int(math.ceil(cu + half_u)) + 1)
    v0, v1 = max(0, int(cv - half_v)), min(rows, int(math.ceil(cv + half_v)) + 1)
    if u1 - u0 < 8 or v1 - v0 < 8:
        return np.zeros((0, 2)), np.zeros((0, DESCRIPTOR_LENGTH), dtype=np.uint8)
    xy, desc = detect_keypoints(image[v0:v1, u0:u1])
    xy = xy + (u0, v0)
    turned = rotate_points(xy - np.asarray(hypothesis.position),
                           0.0 if upright else -hypothesis.inplane)
    return turned / hypothesis.scale, desc


def view_inliers(xy: NDArray[np.float64], desc: NDArray[np.uint8], model: PoseModel,
                 views: NDArray[np.int64]) -> list[NDArray[np.int64]]:
    """Each view's inliers: (test keypoint, model keypoint) index pairs that a similarity
    fitted by RANSAC takes within :data:`INLIER_SHARE` of the view's box diagonal."""
    assert model.keypoint_xy is not None and model.keypoint_descriptor is not None
    assert model.keypoint_view is not None
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    test = desc.astype(np.float32)
    out = []
    for k in views:
        own = np.flatnonzero(model.keypoint_view == k)
        none = np.zeros((0, 2), dtype=np.int64)
        if len(own) < 2 or len(test) < 2:
            out.append(none)
            continue
        knn = matcher.knnMatch(test, model.keypoint_descriptor[own].astype(np.float32), k=2)
        pairs = np.array([(m[0].queryIdx, own[m[0].trainIdx]) for m in knn
                          if len(m) == 2 and m[0].distance < MATCH_RATIO * m[1].distance],
                         dtype=np.int64).reshape(-1, 2)
        # One test keypoint per view keypoint: a repeated texture of the clutter matches
        # many onto one, which a shrunk similarity takes as inliers.
        pairs = pairs[np.unique(pairs[:, 1], return_index=True)[1]]
        if len(pairs) < MIN_SHARED:
            out.append(none)
            continue
        tolerance = INLIER_SHARE * float(np.hypot(*model.view_box[k]))
        fitted, inlier = cv2.estimateAffinePartial2D(
            xy[pairs[:, 0]].astype(np.float32),
            model.keypoint_xy[pairs[:, 1]].astype(np.float32), method=cv2.RANSAC,
            ransacReprojThreshold=tolerance, maxIters=500, refineIters=5)
        plausible = fitted is not None and _plausible(fitted)
        out.append(pairs[inlier.ravel() > 0] if plausible else none)
    return out


def _plausible(fitted: NDArray[Any]) -> bool:
    """Whether a similarity (2 x 3) keeps the mode's scale within :data:`MAX_SCALE` and its
    in-plane angle within :data:`MAX_TURN`."""
    scale = math.hypot(fitted[0, 0], fitted[1, 0])
    turn = math.atan2(fitted[1, 0], fitted[0, 0])
    return 1.0 / MAX_SCALE <= scale <= MAX_SCALE and abs(turn) <= MAX_TURN


def share_between(test: NDArray[np.float64], start: NDArray[np.float64],
                  end: NDArray[np.float64]) -> float | None:
    """How far from one view to the next the test view lies: ``t`` in
    ``test ~ s ((1 - t) start + t end) + c``, by least squares.

    Parameters
    ----------
    test, start, end : ndarray, shape (N, 2)
        The same keypoints in the test image and in the two views (features'
        frame).

    Returns
    -------
    float or None
        ``t`` (0 at ``start``, 1 at ``end``); None where the keypoints do not
        move between the views or the test scale ``s`` is off by more than 2x.

    Notes
    -----
    The keypoints off the fit by more than :data:`TRIM_SPREAD` times the
    median residual are dropped and the fit made again, :data:`TRIM_ROUNDS`
    times. The shift ``c`` takes up the reference points' offset, the scale ``s`` the
    estimate's scale error; each keypoint's own motion ``end - start`` differs
    from the others' (parallax), which the shift cannot take up.
    """
    keep = np.ones(len(test), dtype=bool)
    t = None
    for _ in range(TRIM_ROUNDS + 1):
        fitted = _fit_share(test[keep], start[keep], end[keep])
        if fitted is None:
            return t
        t, s = fitted
        residual = test / s - (1.0 - t) * start - t * end
        residual = np.hypot(*(residual - residual[keep].mean(axis=0)).T)
        keep = residual <= max(TRIM_FLOOR, TRIM_SPREAD * float(np.median(residual[keep])))
        if keep.sum() < MIN_SHARED:
            break
    return t


def _fit_share(test: NDArray[np.float64], start: NDArray[np.float64], end: NDArray[np.float64]
               ) -> tuple[float, float] | None:
    """``(t, s)`` of :func:`share_between` on all the given keypoints, alternating between
    the scale and the share."""
    motion = end - start
    spread = motion - motion.mean(axis=0)
    if float((spread * spread).sum()) < 1e-9:
        return None
    t, s = 0.5, 1.0
    for _ in range(5):
        mid = (1.0 - t) * start + t * end
        mid_c, test_c = mid - mid.mean(axis=0), test - test.mean(axis=0)
        s = float((test_c * mid_c).sum() / max(float((mid_c * mid_c).sum()), 1e-12))
        if not 0.5 < s < 2.0:
            return None
        moved = test / s - start
        t = float((spread * (moved - moved.mean(axis=0))).sum() / (spread * spread).sum())
    return t, s


def image_keypoints(image: NDArray[np.floating]
                    ) -> tuple[NDArray[np.float64], NDArray[np.uint8]]:
    """The whole image's keypoints that :func:`keypoint_locate` looks for the object among:
    at most :data:`LOCATE_KEYPOINTS` per 640 x 480 of it, SIFT's strongest."""
    return detect_keypoints(image, limit=area_budget(LOCATE_KEYPOINTS, image.shape))


def keypoint_locate(hypothesis: Hypothesis, model: PoseModel, image: NDArray[np.floating],
                    *, upright: bool = False,
                    keypoints: tuple[NDArray[np.float64], NDArray[np.uint8]] | None = None
                    ) -> tuple[Hypothesis, float] | None:
    """The object where the whole image's keypoints find it, where the best mode's box holds
    none of its texture.

    The image's keypoints (at most :data:`LOCATE_KEYPOINTS` per 640 x 480 of it, SIFT's
    strongest) are matched to each view's (each view keypoint's nearest test keypoint,
    Lowe's ratio against the second nearest), and a similarity fitted by RANSAC takes each
    view's matched keypoints onto the image; the view of most inliers places the object
    (position, scale, in-plane angle from the similarity). It replaces the mode where it
    holds at least :data:`MIN_INLIERS`, :data:`LOCATE_RATIO` times the inliers of any view in
    the mode's own box, its scale lies within the scales any search may be given
    (:data:`~posevote.inference.setup.SCALE_LIMITS`), and its box overlaps the mode's by
    IoU under 0.5 (the mode is elsewhere).

    Parameters
    ----------
    hypothesis : Hypothesis
        The best mode (image pixels).
    model : PoseModel
        A model of one instance, with keypoints.
    image : ndarray, shape (H, W)
        The grey test image in [0, 1].
    upright : bool, optional
        The search held the object upright: a similarity that turns it by more than
        :data:`MAX_TURN` places nothing.
    keypoints : (ndarray, ndarray), optional
        The image's :func:`image_keypoints`, where already read.

    Returns
    -------
    (Hypothesis, float) or None
        The located pose at the view's viewpoint (its score the mode's: the caller scores
        it) and the texture's evidence for its side: the view's share of its own inliers and
        those of the best view more than :data:`NEAR_ANGLE` from it (the search's profile
        peaked elsewhere and says nothing of it); None where the keypoints do not place
        the object elsewhere.

    Raises
    ------
    ValueError
        If the model has no keypoints (fitted without the keypoint step).
    """
    _need_keypoints(model)
    assert model.keypoint_xy is not None and model.keypoint_descriptor is not None
    assert model.keypoint_view is not None
    xy, desc = image_keypoints(image) if keypoints is None else keypoints
    if len(xy) < MIN_INLIERS or len(model.keypoint_view) < MIN_INLIERS:
        return None
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    knn = matcher.knnMatch(model.keypoint_descriptor.astype(np.float32),
                           desc.astype(np.float32), k=2)
    pairs = np.array([(m[0].trainIdx, m[0].queryIdx) for m in knn
                      if len(m) == 2 and m[0].distance < MATCH_RATIO * m[1].distance],
                     dtype=np.int64).reshape(-1, 2)
    best: tuple[int, int, NDArray[Any]] | None = None
    counts = np.zeros(model.n_views, dtype=np.int64)
    view_of = model.keypoint_view[pairs[:, 1]]
    for k in np.unique(view_of):
        mine = pairs[view_of == k]
        if len(mine) < MIN_INLIERS:
            continue
        tolerance = INLIER_SHARE * float(np.hypot(*model.view_box[k]))
        # Image pixels onto the view's reference pixels: the tolerance in the view's units
        # is scaled by the similarity's own scale after the fit.
        fitted, inlier = cv2.estimateAffinePartial2D(
            model.keypoint_xy[mine[:, 1]].astype(np.float32),
            xy[mine[:, 0]].astype(np.float32), method=cv2.RANSAC,
            ransacReprojThreshold=tolerance * _median_scale(xy[mine[:, 0]],
                                                            model.keypoint_xy[mine[:, 1]]),
            maxIters=500, refineIters=5)
        if fitted is None:
            continue
        count = counts[k] = int(inlier.sum())
        if count >= MIN_INLIERS and (best is None or count > best[1]):
            best = (int(k), count, fitted)
    if best is None:
        return None
    k, count, fitted = best
    scale = math.hypot(fitted[0, 0], fitted[1, 0])
    inplane = math.atan2(fitted[1, 0], fitted[0, 0])
    # Clutter matched many view keypoints onto one point, and a similarity shrunk to it held
    # them all: a size no search could be asked for places nothing.
    if not SCALE_LIMITS[0] <= scale <= SCALE_LIMITS[1] or (upright and abs(inplane) > MAX_TURN):
        return None
    position = np.asarray(fitted[:, 2], dtype=np.float64)
    located = replace(hypothesis, azimuth=float(model.view_azimuth[k]),
                      elevation=float(model.view_elevation[k]), inplane=float(inplane),
                      scale=float(scale), position=(float(position[0]), float(position[1])),
                      box=box_from_pose(position, model.view_box[k] * scale, inplane),
                      refined=False)
    if box_iou(located.box, hypothesis.box) >= 0.5:
        return None
    here = view_inliers(*test_keypoints(image, hypothesis, upright=upright), model,
                        np.arange(model.n_views))
    if count < LOCATE_RATIO * max(max((len(i) for i in here), default=0), 1):
        return None
    direction = viewing_direction(model.view_azimuth, model.view_elevation)
    far = direction @ direction[k] < math.cos(NEAR_ANGLE)
    return located, count / (count + int(counts[far].max(initial=0)))


def _need_keypoints(model: PoseModel) -> None:
    """Refuse a model fitted without the keypoint step (it holds no keypoints)."""
    if model.keypoint_xy is None:
        raise ValueError("the keypoint step needs the views' keypoints, learnt when the model "
                         "is fitted with it; fit (or retrain) with "
                         "refine=RefineOptions(keypoints=True)")


def _median_scale(test: NDArray[np.float64], view: NDArray[np.float64]) -> float:
    """The median ratio of the test keypoints' distances from their centroid to the view's:
    the similarity's scale, roughly, before it is fitted."""
    t = np.hypot(*(test - np.median(test, axis=0)).T)
    v = np.hypot(*(view - np.median(view, axis=0)).T)
    ok = v > 1e-9
    return float(np.median(t[ok] / v[ok])) if ok.any() else 1.0


def keypoint_refine(hypothesis: Hypothesis, model: PoseModel, image: NDArray[np.floating],
                    *, views: NDArray[np.int64] | None = None, upright: bool = False
                    ) -> tuple[Hypothesis, float | None]:
    """The best mode turned to the side its texture shows, its viewpoint read between the
    training views.

    Parameters
    ----------
    hypothesis : Hypothesis
        The best mode (image pixels).
    model : PoseModel
        A model with keypoints (``keypoint_xy``).
    image : ndarray, shape (H, W)
        The grey test image in [0, 1].
    views : ndarray of int, optional
        The views to compare (default: all; a recognised instance's).
    upright : bool, optional
        The search held the object upright (in-plane range 0): the test
        keypoints are not turned by the in-plane angle a refinement gave the
        mode (the reading between views is sensitive to a degree of turn).

    Returns
    -------
    Hypothesis
        The mode with its viewpoint from the keypoints (its score, scale,
        in-plane angle and position kept), or ``hypothesis`` where too few
        keypoints match.
    float or None
        Where it was turned to a view more than :data:`TURN_ANGLE` away: that
        view's share of its own and the near views' inliers (the texture's
        evidence for the side, which the probability reads as the mode's
        share); None where it was not turned.

    Raises
    ------
    ValueError
        If the model has no keypoints (fitted without the keypoint step).
    """
    _need_keypoints(model)
    views = np.arange(model.n_views) if views is None else np.asarray(views, dtype=np.int64)
    xy, desc = test_keypoints(image, hypothesis, upright=upright)
    if len(xy) < MIN_INLIERS or len(views) == 0:
        return hypothesis, None
    inliers = view_inliers(xy, desc, model, views)
    counts = np.array([len(i) for i in inliers])
    best = int(np.argmax(counts))
    if counts[best] < MIN_INLIERS:
        return hypothesis, None
    direction = viewing_direction(model.view_azimuth[views], model.view_elevation[views])
    here = viewing_direction(hypothesis.azimuth, hypothesis.elevation)
    away = np.arccos(np.clip(direction @ here, -1.0, 1.0))
    near_count = int(counts[away <= NEAR_ANGLE].max(initial=0))
    turned = bool(away[best] > TURN_ANGLE and counts[best] >= TURN_RATIO * max(near_count, 1))
    if not turned and away[best] > NEAR_ANGLE:
        return hypothesis, None
    # The best view's neighbours (its ring's two, and over the sphere its column's), of
    # which the test view lies toward the one of most inliers that it has moved toward.
    ring = view_neighbours(model.view_azimuth[views], model.view_elevation[views],
                           model.view_instance[views])[best]
    near = ring[ring >= 0]
    t, other = None, best
    for other in near[np.argsort(-counts[near], kind="stable")]:
        t = _between(xy, model, inliers[best], inliers[other])
        if t is not None and t >= 0.0:
            break
        t = None
    if t is None and not turned:
        return hypothesis, None
    azimuth = float(model.view_azimuth[views[best]])
    elevation = float(model.view_elevation[views[best]])
    if t is not None:
        t = min(t, 1.0)
        turn = float(angle_difference(model.view_azimuth[views[other]], azimuth))
        rise = float(model.view_elevation[views[other]] - elevation)
        azimuth += t * turn
        elevation += t * rise
        if not turned:
            # Read along a ring, the fit's elevation stands; along a column, its azimuth.
            if abs(rise) < 1e-6:
                elevation = hypothesis.elevation
            elif abs(turn) < 1e-6:
                azimuth = hypothesis.azimuth
    moved = replace(hypothesis, azimuth=float(np.mod(azimuth, 2.0 * np.pi)),
                    elevation=elevation)
    return moved, float(counts[best] / (counts[best] + near_count)) if turned else None


def _between(xy: NDArray[np.float64], model: PoseModel, first: NDArray[np.int64],
             second: NDArray[np.int64]) -> float | None:
    """:func:`share_between` on the test keypoints that are inliers of both views."""
    assert model.keypoint_xy is not None
    in_first = dict(zip(first[:, 0].tolist(), first[:, 1].tolist(), strict=True))
    in_second = dict(zip(second[:, 0].tolist(), second[:, 1].tolist(), strict=True))
    shared = sorted(set(in_first) & set(in_second))
    if len(shared) < MIN_SHARED:
        return None
    return share_between(xy[shared], model.keypoint_xy[[in_first[q] for q in shared]],
                         model.keypoint_xy[[in_second[q] for q in shared]])
