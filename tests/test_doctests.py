"""The public API's Examples run as doctests: what the docstrings show is what the code does."""

from __future__ import annotations

import doctest
import importlib

import pytest

#: The modules whose docstrings carry the public API's examples.
MODULES = ("posevote.estimator", "posevote.camera", "posevote.data.training_set",
           "posevote.data.bop", "posevote.data.toy", "posevote.batch", "posevote.evaluation.metrics")


@pytest.fixture(scope="module")
def toy_estimator():
    from posevote import PoseEstimator
    from posevote.data import toy_views

    images, poses, boxes = toy_views(range(0, 360, 20))
    return PoseEstimator.from_preset("default").fit(images, poses, boxes=boxes)


@pytest.mark.parametrize("name", MODULES)
def test_the_examples_run(name, toy_estimator):
    from posevote.data import toy_views

    module = importlib.import_module(name)
    # A method's example uses the estimator its class's example fitted.
    result = doctest.testmod(module, extraglobs={"estimator": toy_estimator,
                                                 "toy_views": toy_views},
                             optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0, f"{name} has no examples"
    assert result.failed == 0


def test_every_public_entry_point_has_an_example():
    from posevote import PoseEstimator
    from posevote.batch import estimate_images
    from posevote.camera import Camera
    from posevote.data import read_poses_csv
    from posevote.data.bop import read_bop_scene

    entries = [PoseEstimator, PoseEstimator.from_preset, PoseEstimator.fit,
               PoseEstimator.partial_fit, PoseEstimator.estimate, PoseEstimator.estimate_objects,
               PoseEstimator.save, PoseEstimator.load, Camera, read_poses_csv, read_bop_scene,
               estimate_images]
    missing = [e.__qualname__ for e in entries if "Examples\n" not in (e.__doc__ or "")]
    assert not missing
