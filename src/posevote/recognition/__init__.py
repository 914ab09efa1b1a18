"""Instance recognition (Sec. III-B): which instance of a category model is in the image,
and the pose again with its own model.

One home: the scores of Eqs. 5-6 (:mod:`~posevote.recognition.score`) and the
recognise step (:mod:`~posevote.recognition.refine`), switched by
:class:`RecognitionOptions` (``PoseEstimator(recognition=None)``: off; a model of
one instance has nothing to recognise).
"""

from __future__ import annotations

from dataclasses import dataclass

from posevote._options import Options


@dataclass(frozen=True, kw_only=True, repr=False)
class RecognitionOptions(Options):
    """Instance recognition and re-estimation for models of several instances (Sec. III-B).

    Attributes
    ----------
    margin : float, default 1.05
        The winner's score must be at least this multiple of the runner-up's
        (chosen by the COIL category cross-validation on training views;
        1.0 always refines with the most similar instance).
    search : bool, default True
        Each instance's full model estimates the pose on its own and the
        instances are judged at their own estimates (beyond the paper);
        False: the paper's scoring at the category's modes and re-estimation
        near them.
    """

    margin: float = 1.05
    search: bool = True

    def __post_init__(self) -> None:
        self._number("margin", low=1.0, high=100.0)
        self._flag("search")
