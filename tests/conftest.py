"""Shared fixtures: synthetic shapes drawn at known poses, and the real data when present."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from posevote.data.training_set import TrainingSet
from posevote.evaluation.protocols import Protocol, Row, Split

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def draw_object(azimuth: float, *, size: int = 128, scale: float = 1.0, inplane: float = 0.0,
                centre: tuple[float, float] | None = None) -> np.ndarray:
    """A flat asymmetric 'object' whose outline changes with azimuth.

    An L-shaped plate and a notch, foreshortened by cos(azimuth) horizontally
    as if turned on a turntable, plus a marker that shows which face is in
    front. Drawn with anti-aliasing on black, then rotated and scaled.
    """
    img = np.zeros((size, size), np.float32)
    c = np.array([size / 2.0, size / 2.0])
    squash = 0.35 + 0.65 * abs(np.cos(azimuth))
    side = 1.0 if np.cos(azimuth) >= 0 else -1.0
    pts = np.array([[-30, -30], [10, -30], [10, -5], [30, -5], [30, 30], [-30, 30]], float)
    pts[:, 0] *= squash * side
    pts[:, 0] += 12 * np.sin(azimuth)
    cv2.fillPoly(img, [np.round(pts + c).astype(np.int32)], 0.8, lineType=cv2.LINE_AA)
    marker = np.array([-15.0 * squash * side + 12 * np.sin(azimuth), 12.0])
    cv2.circle(img, tuple(int(round(x)) for x in marker + c), 6, 0.3, -1, lineType=cv2.LINE_AA)
    stripe_x = int(round(c[0] + 12 * np.sin(azimuth) + 20 * np.sin(2 * azimuth)))
    cv2.line(img, (stripe_x, int(c[1] - 25)), (stripe_x, int(c[1] + 25)), 0.45, 2, cv2.LINE_AA)
    if scale != 1.0 or inplane != 0.0 or centre is not None:
        dst = np.array(centre if centre is not None else c)
        rot = scale * np.array([[np.cos(inplane), -np.sin(inplane)],
                                [np.sin(inplane), np.cos(inplane)]])
        M = np.hstack([rot, (dst - rot @ c)[:, None]])
        img = cv2.warpAffine(img, M, (size, size), flags=cv2.INTER_LINEAR)
    return img.astype(np.float64)


@pytest.fixture(scope="session")
def synthetic_training():
    """18 views at 0, 20, ..., 340 degrees with their boxes."""
    from posevote.data import object_box

    az = np.radians(np.arange(0, 360, 20))
    images = [draw_object(a) for a in az]
    boxes = np.array([object_box(im) for im in images])
    return images, az, boxes


@pytest.fixture(scope="session")
def fitted_estimator(synthetic_training):
    from posevote import PoseEstimator

    images, az, boxes = synthetic_training
    return PoseEstimator().fit(images, az, boxes=boxes)


@pytest.fixture
def coil_dir():
    path = SHARED_DATA / "coil-100"
    if not path.is_dir():
        pytest.skip("../shared/data/coil-100 is not present")
    return path


@pytest.fixture
def epfl_dir():
    path = SHARED_DATA / "epfl-gims08" / "tripod-seq"
    if not path.is_dir():
        pytest.skip("../shared/data/epfl-gims08 is not present")
    return path


@pytest.fixture(scope="session")
def draw():
    """The synthetic object renderer, for tests that need other poses."""
    return draw_object


def _segments(ends, step=2.0):
    """Edge points every ``step`` px along segments ``(a, b)``, with their tangents."""
    from posevote.features import EdgeFeatures

    xy, theta = [], []
    for a, b in (np.asarray(e, dtype=np.float64) for e in ends):
        n = max(int(np.linalg.norm(b - a) / step), 1)
        xy.append(a + (np.arange(n)[:, None] / n) * (b - a))
        theta.append(np.full(n, np.mod(np.arctan2(*(b - a)[::-1]), np.pi)))
    return EdgeFeatures(xy=np.concatenate(xy), theta=np.concatenate(theta))


def _square(half):
    """The four sides of a square centred on the origin, as segments."""
    c = [[-half, -half], [half, -half], [half, half], [-half, half]]
    return [(c[k], c[(k + 1) % 4]) for k in range(4)]


@pytest.fixture(scope="session")
def line_drawing():
    """``(segments, square)``: edge features drawn along segments, and a square's sides."""
    return _segments, _square


def _toy_model(shared_feature=True):
    """Three views; view features at distinct places plus one feature common to all."""
    from posevote.features import EdgeFeatures
    from posevote.model import build_model

    views = []
    for k in range(3):
        xy = [[10.0 * k - 10, 5.0]]
        theta = [0.3 * k]
        if shared_feature:
            xy.append([0.0, -20.0])
            theta.append(1.0)
        views.append(EdgeFeatures(xy=np.array(xy) + 50, theta=np.array(theta)))
    return build_model(views, poses=np.radians([[0, 0, 0], [120, 0, 0], [240, 0, 0]]),
                       centers=np.full((3, 2), 50.0), scales=np.ones(3),
                       box_sizes=np.full((3, 2), 40.0), instances=[0, 0, 0],
                       instance_names=["toy"], reference_size=40.0)


@pytest.fixture
def toy_model():
    """A builder of a three-view toy model (call it; ``shared_feature=False`` drops the common feature)."""
    return _toy_model


@pytest.fixture
def placed(draw):
    """``placed(azimuth, centre=(110, 90))``: the synthetic object on a 200 x 220 canvas, and its box."""
    def place(azimuth, centre=(110.0, 90.0)):
        from posevote.data import object_box

        img = np.zeros((200, 220))
        obj = draw(azimuth, size=96)
        x0, y0 = int(centre[0] - 48), int(centre[1] - 48)
        img[y0:y0 + 96, x0:x0 + 96] = obj
        x, y, w, h = object_box(obj)
        return img, (x + x0, y + y0, w, h)

    return place


@pytest.fixture()
def tiny_protocol(tmp_path_factory, synthetic_training, draw):
    from posevote.data import object_box

    images, az, boxes = synthetic_training
    folder = tmp_path_factory.mktemp("tiny")
    paths = []
    for i, img in enumerate(images):
        p = folder / f"train_{i:02d}.png"
        cv2.imwrite(str(p), (img * 255).astype(np.uint8))
        paths.append(p)
    test_paths, test_az, test_boxes = [], [], []
    for i, a in enumerate(np.radians([30.0, 110.0, 250.0, 330.0])):
        img = draw(a)
        p = folder / f"test_{i}.png"
        cv2.imwrite(str(p), (img * 255).astype(np.uint8))
        test_paths.append(p)
        test_az.append([a, 0.0, 0.0])
        test_boxes.append(object_box(img))
    train = TrainingSet(images=tuple(paths), poses=np.column_stack([az, 0 * az, 0 * az]),
                        boxes=boxes, masks=(None,) * len(paths), instances=("toy",) * len(paths))
    test = TrainingSet(images=tuple(test_paths), poses=np.array(test_az),
                       boxes=np.array(test_boxes), masks=(None,) * 4, instances=("toy",) * 4)
    split = Split(name="only", train=train, test=test, groups=("seen",) * 4)
    return Protocol(name="tiny", description="synthetic", splits=(split,),
                    rows=(Row(name="weights + fitting", params={}),
                          Row(name="later", params=None, note="arrives later")))


@pytest.fixture(scope="session")
def training_folder(tmp_path_factory, synthetic_training):
    """A training folder (poses.csv with boxes) of the synthetic object's 18 views."""
    images, az, boxes = synthetic_training
    folder = tmp_path_factory.mktemp("train")
    lines = ["image,azimuth_deg,box_x,box_y,box_w,box_h"]
    for i, (img, a, b) in enumerate(zip(images, az, boxes, strict=True)):
        cv2.imwrite(str(folder / f"v{i:02d}.png"), (img * 255).astype(np.uint8))
        lines.append(f"v{i:02d}.png,{np.degrees(a):.1f},{b[0]},{b[1]},{b[2]},{b[3]}")
    (folder / "poses.csv").write_text("\n".join(lines) + "\n")
    return folder


@pytest.fixture(scope="session")
def saved_model(fitted_estimator, tmp_path_factory):
    """The fitted estimator's model file."""
    path = tmp_path_factory.mktemp("model") / "model.npz"
    fitted_estimator.save(path)
    return path


@pytest.fixture
def vote_scene():
    """A view's features, a pose, and test maps of the features placed there amid clutter."""
    from posevote.features import EdgeFeatures
    from posevote.scoring.maps import prepare_test

    rng = np.random.default_rng(3)
    train_xy = rng.uniform(-20, 20, (40, 2))
    train_theta = rng.uniform(0, np.pi, 40)
    train_w = rng.uniform(0.2, 1.0, 40)
    train_w /= train_w.sum()
    alpha, scale, t = 0.2, 1.1, np.array([70.0, 50.0])
    c, s = np.cos(alpha), np.sin(alpha)
    moved = scale * train_xy @ np.array([[c, s], [-s, c]]) + t
    clutter = rng.uniform(0, 120, (60, 2))
    test = EdgeFeatures(xy=np.vstack([moved, clutter]),
                        theta=np.mod(np.concatenate([train_theta + alpha,
                                                     rng.uniform(0, np.pi, 60)]), np.pi))
    maps = prepare_test(test, (100, 120), position_sigma=2.0, orientation_kappa=8.0)
    return train_xy, train_theta, train_w, alpha, scale, t, maps
