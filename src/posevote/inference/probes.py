"""The search's output: probes of p(w) over viewpoint x in-plane angle x scale (Fig. 2)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from posevote.geometry import viewing_direction
from posevote.scoring.score import median_spacing


@dataclass(frozen=True, kw_only=True, eq=False)
class ProbeSet:
    """Discrete approximations of p(w) (the output of Fig. 2).

    Attributes
    ----------
    azimuth, elevation : ndarray, shape (V,)
        Probed viewpoints, radians.
    inplane : ndarray, shape (A,)
        Probed in-plane angles, radians.
    scale : ndarray, shape (S,)
        Probed scales.
    score : ndarray, shape (V, A, S)
        p(w) at the best translation of each probe.
    translation : ndarray, shape (V, A, S, 2)
        That translation: the reference point ``(u, v)``, pixels.
    box : ndarray, shape (V, 2)
        Object box width and height at each viewpoint, model units.
    probed : ndarray of bool, shape (V, A, S), or None
        The probes a ranking search probed (the others score 0 without
        having been scored); None: every probe.
    """

    azimuth: NDArray[np.float64]
    elevation: NDArray[np.float64]
    inplane: NDArray[np.float64]
    scale: NDArray[np.float64]
    score: NDArray[np.float64]
    translation: NDArray[np.float64]
    box: NDArray[np.float64]
    probed: NDArray[np.bool_] | None = None

    @cached_property
    def directions(self) -> NDArray[np.float64]:
        """Viewing direction of each probed viewpoint, shape (V, 3)."""
        return viewing_direction(self.azimuth, self.elevation)

    @cached_property
    def spacing(self) -> float:
        """Median angle between a probed viewpoint and its nearest neighbour, radians (pi
        for fewer than two); cached, as every fit of the probes' modes reads it."""
        return median_spacing(self.directions)

    def boxes(self) -> NDArray[np.float64]:
        """Box ``(x, y, w, h)`` of every probe, pixels, shape (V, A, S, 4)."""
        size = np.broadcast_to(self.box[:, None, None, :] * self.scale[None, None, :, None],
                               self.translation.shape)
        return np.concatenate([self.translation - size / 2.0, size], axis=-1)

    @property
    def turntable(self) -> bool:
        """True when every probe has the same elevation (only azimuth varies)."""
        return bool(np.ptp(self.elevation) < 1e-9) if len(self.elevation) else True


def probe_spacing(probes: ProbeSet) -> float:
    """Median angle between a probed viewpoint and its nearest neighbour."""
    return probes.spacing
