"""Stage 4: probes become continuous pose hypotheses (Sec. II-B), and the switches of the
refinement steps (:class:`RefineOptions`)."""

from __future__ import annotations

from dataclasses import dataclass

from posevote._options import Options

#: The local refinements :attr:`RefineOptions.local` names.
LOCAL_REFINEMENTS = (None, "polish", "profile")


@dataclass(frozen=True, kw_only=True, repr=False)
class RefineOptions(Options):
    """Which refinement steps of the estimate run (each its own switch).

    Attributes
    ----------
    fit : bool, default True
        Fit each mode's pose to the probes around it (Sec. II-B,
        :func:`~posevote.refinement.fitting.refine_mode`); False keeps the best
        probe of each mode (the paper's ablation "without fitting").
    rescale : bool, default True
        Polish the best mode's scale and position on the narrow kernel, its
        angles and score kept (:func:`~posevote.refinement.local.rescale_mode`;
        a model of one instance: a category's pooled views pull the narrow
        kernel onto inner edges).
    local : {None, "polish", "profile"}, default None
        Refine the best mode on the exact p(w) with the narrow kernel
        (:func:`~posevote.refinement.local.local_refine`): ``"polish"`` its
        in-plane angle, scale and position; ``"profile"`` also its viewpoint,
        fitted to the polished scores of the viewpoints around it.
    share_scale : bool, default False
        Set the best mode's scale where its narrow score times the share of
        the test edges it explains peaks
        (:func:`~posevote.refinement.share.share_scale`).
    outline : bool, default True
        Give each mode the box of its views' outline, where the model learnt
        outlines from masks (:mod:`posevote.model.outline`).
    keypoints : bool, default False
        Turn the best mode to the side its texture shows and read its
        viewpoint between the training views from SIFT keypoints matched to
        theirs (:func:`~posevote.keypoints.refine.keypoint_refine`; training
        keeps each view's keypoints).
    """

    fit: bool = True
    rescale: bool = True
    local: str | None = None
    share_scale: bool = False
    outline: bool = True
    keypoints: bool = False

    def __post_init__(self) -> None:
        for name in ("fit", "rescale", "share_scale", "outline", "keypoints"):
            self._flag(name)
        if self.local not in LOCAL_REFINEMENTS:
            self._fail("local", f"one of {', '.join(map(repr, LOCAL_REFINEMENTS))}", self.local)
