import numpy as np
import pytest

from posevote.features.edges import EdgeFeatures
from posevote.inference.search import SearchOptions, SearchSetup, image_maps
from posevote.model.density import build_model
from posevote.refinement.halfturn import half_turn
from posevote.results import Hypothesis

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


def _model(sides):
    views = [EdgeFeatures(xy=f.xy + 50.0, theta=f.theta) for f in sides]
    return build_model(views, poses=np.array([[0.0, 0.0, 0.0], [np.pi, 0.0, 0.0]]),
                       centers=np.full((2, 2), 50.0), scales=np.ones(2),
                       box_sizes=np.array([[40.0, 40.0], [47.0, 47.0]]), instances=[0, 0],
                       instance_names=["toy"], reference_size=40.0)


def _pose(azimuth, scale, position=(80.0, 80.0)):
    side = 40.0 * scale / (_BACK if azimuth else 1.0)
    return Hypothesis(azimuth=azimuth, elevation=0.0, inplane=0.0, scale=scale,
                      position=position, box=(position[0] - side / 2, position[1] - side / 2,
                                              side, side), score=1.0, refined=True)


def _turn(pose, model, view, correlate=None):
    """``half_turn`` of ``pose`` in an image that shows ``view`` at (80, 80)."""
    feats = EdgeFeatures(xy=view.xy + 80.0, theta=view.theta)
    found, turned = half_turn(pose, model, image_maps(feats, (160, 160), _SETUP), _SETUP,
                              correlate or _flat, features=feats, shape=(160, 160))
    assert turned == (found is not pose)
    return found


def _flat(poses):
    return np.ones(len(poses))


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


def test_the_correlation_weighs_in(sides):
    # A half-turn whose grey levels do not match is not taken, however many edges it explains.
    def against_the_face(poses):
        return np.array([0.2 if abs(p.azimuth) < 1.0 else 1.0 for p in poses])

    back = _pose(np.pi, _BACK)
    assert _turn(back, _model(sides), sides[0], against_the_face) is back
