"""The grey-level templates (beyond the paper): each training view's object as a small
upright grey image, and the steps that read it.

One home: the templates learnt at training (:mod:`~posevote.templates.model`), the
re-ranking of the search's best probes and the weighing of poses by their
correlation (:mod:`~posevote.templates.match`), and the half-turn check
(:mod:`~posevote.templates.halfturn`), switched by :class:`TemplateOptions`
(``PoseEstimator(templates=None)``: off, and no templates are learnt).
"""

from __future__ import annotations

from dataclasses import dataclass

from posevote._options import Options


@dataclass(frozen=True, kw_only=True, repr=False)
class TemplateOptions(Options):
    """Which steps read the templates (each its own switch).

    Attributes
    ----------
    rerank : bool, default True
        Re-rank the search's best probes by how well the image matches the
        nearest training view's grey levels under them
        (:func:`~posevote.templates.match.rerank_by_template`).
    weigh : bool, default True
        The local refinement weighs each pose it compares by that match, as
        the re-ranking weighed the probes (in clutter the edges alone let a
        neighbouring view's polish score on the background).
    half_turn : bool, default True
        Check the best mode against its half-turn
        (:func:`~posevote.templates.halfturn.half_turn`).
    """

    rerank: bool = True
    weigh: bool = True
    half_turn: bool = True

    def __post_init__(self) -> None:
        for name in ("rerank", "weigh", "half_turn"):
            self._flag(name)
