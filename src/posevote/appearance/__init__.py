"""The appearance stages (beyond the paper): HOG descriptors of boxes, learnt at training,
verify the search's candidates, regress the best mode's box and give its nearest view.

One home: the descriptors (:mod:`~posevote.appearance.descriptors`), what training
learns from them (:mod:`~posevote.appearance.model`), the verification step
(:mod:`~posevote.appearance.verify`) and the appearance step
(:mod:`~posevote.appearance.refine`), switched by :class:`AppearanceOptions`
(``PoseEstimator(appearance=None)``: off).
"""

from __future__ import annotations

from dataclasses import dataclass

from posevote._options import Options


@dataclass(frozen=True, kw_only=True, repr=False)
class AppearanceOptions(Options):
    """The appearance stages: verification of the search's candidates and the nearest view.

    Beyond the paper. The defaults are the ``category`` preset's, chosen on
    ``epfl-cv`` (docs/DEFAULTS.md).

    Attributes
    ----------
    candidates : int, default 40
        The search's best probes whose (regressed) box is compared with the
        training views; the pose is then estimated again inside the winner's
        box. 0: no verification (the best mode's box is still regressed and
        its viewpoint taken from the nearest view).
    tolerance_deg : float or None, default 40.0
        A candidate is compared with the training views within this angle of
        its viewpoint; None: one probe spacing.
    objectness_weight : float, default 0.5
        Candidates are ranked by their distance to the nearest training view
        minus this times the classifier's score.
    jitter : float, default 0.05
        The final viewpoint is the medoid of the nearest training views of
        the kept box and 26 boxes around it, shifted by this fraction of its
        size and scaled by one plus or minus it; 0: the kept box's alone.
    """

    candidates: int = 40
    tolerance_deg: float | None = 40.0
    objectness_weight: float = 0.5
    jitter: float = 0.05

    def __post_init__(self) -> None:
        self._number("candidates", low=0, high=10_000, integer=True)
        self._number("tolerance_deg", low=0.0, high=180.0, low_open=True, optional=True)
        self._number("objectness_weight", low=0.0, high=100.0)
        self._number("jitter", low=0.0, high=0.5, high_open=True)
