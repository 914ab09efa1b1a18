"""Result types: frozen, keyword-only, radians inside (``*_deg`` views for the edges)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

#: A mode at a view this alike to another side of the object (``Hypothesis.lookalike``)
#: leaves its azimuth undefined (:attr:`PoseEstimate.ambiguous`): chosen on the 40
#: development COIL objects, views every 20 and every 40 degrees, between the objects whose
#: sides differ and those alike from every side (each object's median over its views;
#: docs/DEFAULTS.md).
LOOKALIKE = 0.8


@dataclass(frozen=True, kw_only=True)
class Hypothesis:
    """One mode of the pose likelihood p(w).

    Attributes
    ----------
    azimuth, elevation, inplane : float
        Viewpoint ``w1`` and in-plane angle of ``w2``, radians.
    scale : float
        Apparent size relative to the training images (``w2``).
    position : (float, float)
        Image position ``(u, v)`` of the object's reference point (``w3``),
        pixels.
    box : (float, float, float, float)
        Object box ``(x, y, w, h)``, pixels: the outline of the views near
        the viewpoint turned, scaled and placed, for a model fitted with
        masks (:mod:`posevote.model.outline`); else their box turned (its
        bounding box, loose under an in-plane angle), or the appearance
        stage's regressed box.
    score : float
        ``p(w)`` at the best probe of this mode: the weighted fraction of the
        model's features explained by the image.
    refined : bool
        Whether the continuous refinement (distribution fitting) succeeded;
        if not, the pose is the best discrete probe.
    R_cam_obj : 3x3 tuple of float or None
        The object's rotation in the camera frame (given a camera;
        :mod:`posevote.camera`).
    t_cam_obj : (float, float, float) or None
        The object's reference point in the camera frame, metres (given a
        camera and a model that knows the object's height).
    probability : float
        Chance that this estimate is right: the true viewpoint within 30
        degrees of this mode's, the box on the object; the best mode's
        calibrated by ``SearchOptions.calibration`` on its preset's
        development folds, wrong answers among them, for the estimates the
        preset reports (:mod:`posevote.refinement.probability`; below the
        preset's ``min_score`` it may overstate); NaN when not computed.
    contrast : float
        ``score`` over the spread of what the same pose scores elsewhere in
        the frame (:mod:`posevote.scoring.contrast`): how far the mode stands
        out of its own frame's background; NaN where the preset does not
        measure it (``SearchOptions.contrast``).
    lookalike : float
        How alike the object looks here to another side of it, 30 degrees or
        more away, in [0, 1]: the share of the edges of the views near this
        viewpoint that the most alike views of other sides explain, and
        they of theirs (:mod:`posevote.refinement.lookalike`); NaN when not
        measured (a model file of an earlier posevote).
    """

    azimuth: float
    elevation: float
    inplane: float
    scale: float
    position: tuple[float, float]
    box: tuple[float, float, float, float]
    score: float
    refined: bool
    R_cam_obj: tuple[tuple[float, float, float], ...] | None = None
    t_cam_obj: tuple[float, float, float] | None = None
    probability: float = float("nan")
    contrast: float = float("nan")
    lookalike: float = float("nan")

    @property
    def detection_score(self) -> float:
        """What ``min_score`` reads: ``contrast`` where measured, else ``score``."""
        return self.score if math.isnan(self.contrast) else self.contrast

    @property
    def T_cam_obj(self) -> list[list[float]] | None:
        """The 4x4 rigid transform from ``R_cam_obj`` and ``t_cam_obj`` (None without both)."""
        if self.R_cam_obj is None or self.t_cam_obj is None:
            return None
        return [[*row, t] for row, t in zip(self.R_cam_obj, self.t_cam_obj, strict=True)] \
            + [[0.0, 0.0, 0.0, 1.0]]

    @property
    def azimuth_deg(self) -> float:
        """Azimuth in degrees, ``[0, 360)``."""
        return math.degrees(self.azimuth) % 360.0

    @property
    def elevation_deg(self) -> float:
        """Elevation in degrees."""
        return math.degrees(self.elevation)

    @property
    def inplane_deg(self) -> float:
        """In-plane angle in degrees, ``[-180, 180)``."""
        return (math.degrees(self.inplane) + 180.0) % 360.0 - 180.0

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for files and reports (degrees, pixels)."""
        return {
            "azimuth_deg": self.azimuth_deg,
            "elevation_deg": self.elevation_deg,
            "inplane_deg": self.inplane_deg,
            "scale": self.scale,
            "position_px": list(self.position),
            "box_px": list(self.box),
            "score": self.score,
            "refined": self.refined,
            "probability": None if math.isnan(self.probability) else self.probability,
            **({} if math.isnan(self.contrast) else {"contrast": self.contrast}),
            **({} if math.isnan(self.lookalike) else {"lookalike": self.lookalike}),
            **({} if self.R_cam_obj is None else {"R_cam_obj": [list(r) for r in self.R_cam_obj]}),
            **({} if self.t_cam_obj is None else {"t_cam_obj_m": list(self.t_cam_obj),
                                                  "T_cam_obj": self.T_cam_obj}),
        }


@dataclass(frozen=True, kw_only=True)
class PoseEstimate:
    """The result of :meth:`posevote.PoseEstimator.estimate`.

    Attributes
    ----------
    found : bool
        False when no pose could be proposed (no edges in the image, or no
        mode's ``detection_score`` was above the estimator's ``min_score``);
        then ``best`` is None.
    best : Hypothesis or None
        The highest-scoring mode.
    modes : tuple of Hypothesis
        All modes kept, best first (``modes[0] is best``); other modes show
        the ambiguities (front/back confusions appear as a second mode).
    n_test_features : int
        Edge features found in the image.
    seconds : float
        Wall time of the estimate.
    instance : str
        Recognised instance ("" when not applicable, or when no instance won
        clearly enough).
    instance_margin : float
        Score of the best instance over that of the runner-up at the
        category estimate (NaN when instances were not scored).
    top_score : float
        The best ``detection_score`` of the modes before ``min_score`` was
        applied (0 when there was none): what a rejected image scored.
    viewpoint_scores : tuple of (float, float, float)
        ``(azimuth, elevation, score)`` of every probed viewpoint, radians:
        the profile the modes and their probabilities come from (where to
        look again). Not in :meth:`to_dict`.
    """

    found: bool
    best: Hypothesis | None
    modes: tuple[Hypothesis, ...] = field(default=())
    n_test_features: int = 0
    seconds: float = 0.0
    instance: str = ""
    instance_margin: float = float("nan")
    top_score: float = 0.0
    viewpoint_scores: tuple[tuple[float, float, float], ...] = ()

    @property
    def ambiguous(self) -> bool:
        """True when the best mode's azimuth is not to be trusted: it is more likely wrong
        than right (probability under 1/2), or the object looks nearly the same from another
        side there (``best.lookalike`` at least :data:`LOOKALIKE`).

        Two modes of a front/back confusion give the first; an object that
        looks the same from every side (a ring, a plain pot: the azimuth is
        undefined) the second. A robot should look again, or treat the object
        as the same from those sides, rather than act on the azimuth.
        """
        best = self.best
        return best is not None and (not best.probability >= 0.5 or best.lookalike >= LOOKALIKE)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for files and reports (degrees, pixels)."""
        return {
            "found": self.found,
            "best": None if self.best is None else self.best.to_dict(),
            "modes": [m.to_dict() for m in self.modes],
            "n_test_features": self.n_test_features,
            "seconds": self.seconds,
            "instance": self.instance,
            "instance_margin": None if math.isnan(self.instance_margin) else self.instance_margin,
            "top_score": self.top_score,
            "ambiguous": self.ambiguous,
        }
