import numpy as np
import pytest

from posevote.features.edges import EdgeFeatures
from posevote.inference.setup import SearchOptions, SearchSetup
from posevote.model.density import build_model
from posevote.results import Hypothesis
from posevote.scoring.score import narrow_maps
from posevote.templates.halfturn import half_turn

_SETUP = SearchSetup(options=SearchOptions(), position_sigma=2.0, edge_spacing=2.0,
                     viewpoint_kappa=10.0)
# The back is framed larger than the face: from the same place it shows at this scale.
_BACK = 0.85


@pytest.fixture
def sides(line_drawing):
    """The face: a square and a cross inside it; the back: the same square only, larger."""
    segments, square = line_drawing
    face = segments(square(20.0) + [([-12.0, 0.0], [12.0, 0.0]), ([0.0, -12.0], [0.0, 12.0])])
    return face, segments(square(20.0 / _BACK))


def _model(sides, elevations=(0.0,)):
    """Both sides at each elevation (several: a model over the sphere)."""
    views = [EdgeFeatures(xy=f.xy + 50.0, theta=f.theta) for _ in elevations for f in sides]
    poses = np.array([[a, e, 0.0] for e in elevations for a in (0.0, np.pi)])
    n = len(poses)
    return build_model(views, poses=poses, centers=np.full((n, 2), 50.0), scales=np.ones(n),
                       box_sizes=np.array([[40.0, 40.0], [47.0, 47.0]] * len(elevations)),
                       instances=[0] * n, instance_names=["toy"], reference_size=40.0)


def _pose(azimuth, scale, position=(80.0, 80.0)):
    side = 40.0 * scale / (_BACK if azimuth else 1.0)
    return Hypothesis(azimuth=azimuth, elevation=0.0, inplane=0.0, scale=scale,
                      position=position, box=(position[0] - side / 2, position[1] - side / 2,
                                              side, side), score=1.0, refined=True)


def _turn(pose, model, view, correlate=None, resemble=None):
    """``half_turn`` of ``pose`` in an image that shows ``view`` at (80, 80)."""
    feats = EdgeFeatures(xy=view.xy + 80.0, theta=view.theta)
    found, turned = half_turn(pose, model, narrow_maps(feats, (160, 160), _SETUP), _SETUP,
                              correlate or _flat, resemble=resemble or _alike, features=feats,
                              shape=(160, 160))
    assert turned == (np.cos(found.azimuth - pose.azimuth) < 0)
    if len(np.unique(model.view_elevation)) == 1:
        assert turned == (found is not pose)         # a turntable's kept pose is the same
    return found


def _flat(poses):
    return np.ones(len(poses))


def _alike(pose):
    return 1.0


def test_the_plain_back_over_the_face_turns_to_the_face(sides):
    found = _turn(_pose(np.pi, _BACK), _model(sides), sides[0])
    assert found.azimuth == pytest.approx(0.0, abs=1e-9)
    assert found.scale == pytest.approx(1.0, abs=0.03)
    assert np.allclose(found.position, (80.0, 80.0), atol=1.0)


def test_the_right_pose_stays(sides):
    model = _model(sides)
    face = _pose(0.0, 1.0)
    assert _turn(face, model, sides[0]) is face
    # The back seen from behind: the face's cross finds nothing there.
    back = _pose(np.pi, 1.0)
    assert _turn(back, model, sides[1]) is back


def test_the_correlation_weighs_in_on_a_turntable(sides):
    # A half-turn whose grey levels do not match is not taken, however many edges it
    # explains; the gradients' likeness is not asked.
    def against_the_face(poses):
        return np.array([0.2 if abs(p.azimuth) < 1.0 else 1.0 for p in poses])

    back = _pose(np.pi, _BACK)
    assert _turn(back, _model(sides), sides[0], against_the_face) is back
    assert _turn(back, _model(sides), sides[0],
                 resemble=lambda pose: against_the_face([pose])[0]) is not back


def test_the_gradients_weigh_in_over_the_sphere(sides):
    # Over the sphere the gradients' likeness to the templates takes the correlation's place.
    model = _model(sides, elevations=(-0.2, 0.0, 0.2))

    def against_the_face(pose):
        return 0.2 if abs(pose.azimuth) < 1.0 else 1.0

    back = _pose(np.pi, _BACK)
    assert _turn(back, model, sides[0], resemble=against_the_face).azimuth == pytest.approx(np.pi)
    assert _turn(back, model, sides[0]).azimuth == pytest.approx(0.0, abs=0.05)
    assert _turn(back, model, sides[0], correlate=lambda poses: np.array(
        [0.2 if abs(p.azimuth) < 1.0 else 1.0 for p in poses])).azimuth == pytest.approx(
        0.0, abs=0.05)
