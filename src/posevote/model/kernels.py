"""Kernels of the pose and appearance densities (Eqs. 1-3).

All kernels here are *max-normalised* (peak value 1). The normalising
constants of Eqs. 1-2 are the same for every pose, so they change no argmax;
peak-1 kernels make scores read as "fraction of the model's (weighted)
features explained by the image".

For Gaussian and von Mises kernels the integral of Eq. 3 over a product of a
training kernel and a test kernel is again a kernel of the same family with a
wider bandwidth (variances add for Gaussians). posevote is parametrised by
that *combined* kernel directly: ``position_sigma`` and ``orientation_kappa``
describe ``int K2(x, x_i) K2(x, x_j) dx`` as a function of ``x_i - x_j``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from posevote._options import Options

#: Combined orientation kernel concentration (doubled angles): no shipped
#: configuration changes it; 8 passes edges within about 17 degrees.
ORIENTATION_KAPPA = 8.0
#: Training views whose pose kernel K1 is below this take no part in a
#: viewpoint's probe or score: they would add features at negligible weight.
K1_CUTOFF = 0.1


@dataclass(frozen=True, kw_only=True, repr=False)
class KernelOptions(Options):
    """Widths of the kernels of psi, phi and p(w) (Eqs. 1-3).

    Attributes
    ----------
    position_sigma : float, default 3.0
        Combined appearance kernel width in position, pixels at scale 1.
    viewpoint_bandwidth_deg : float or None, default None
        Half width at half maximum of the pose kernel K1 on viewpoints;
        None: half the median spacing of the training viewpoints
        (:data:`posevote.model.density.MORPH_BANDWIDTH` spacings for
        morphed models).
    """

    position_sigma: float = 3.0
    viewpoint_bandwidth_deg: float | None = None

    def __post_init__(self) -> None:
        self._number("position_sigma", low=0.1, high=100.0)
        self._number("viewpoint_bandwidth_deg", low=0.0, high=180.0, low_open=True,
                     optional=True)


def position_kernel(sq_distance: ArrayLike, sigma: float) -> NDArray[np.float64]:
    """Gaussian on image position: ``exp(-d^2 / (2 sigma^2))``."""
    return np.exp(-np.asarray(sq_distance, dtype=np.float64) / (2.0 * sigma * sigma))


def orientation_kernel(delta: ArrayLike, kappa: float) -> NDArray[np.float64]:
    """Von Mises on the doubled orientation difference (undirected edges).

    ``exp(kappa * (cos(2 * delta) - 1))``: period ``pi`` in ``delta``.
    """
    return np.exp(kappa * (np.cos(2.0 * np.asarray(delta, dtype=np.float64)) - 1.0))


def viewpoint_kernel(direction_a: ArrayLike, direction_b: ArrayLike, kappa: float
                     ) -> NDArray[np.float64]:
    """Von Mises-Fisher kernel on viewing directions (unit 3-vectors), part of K1."""
    dot = np.sum(np.asarray(direction_a) * np.asarray(direction_b), axis=-1)
    return np.exp(kappa * (np.clip(dot, -1.0, 1.0) - 1.0))


def kappa_for_width(width: float, *, level: float = 0.5, doubled: bool = False) -> float:
    """Concentration at which a von Mises kernel falls to ``level`` at ``width``.

    Parameters
    ----------
    width : float
        Angle (radians) at which the kernel should equal ``level``.
    level : float, optional
        Kernel value at ``width`` (0.5: ``width`` is the half width at half
        maximum).
    doubled : bool, optional
        True for the orientation kernel, whose argument is doubled.
    """
    angle = 2.0 * width if doubled else width
    return float(-np.log(level) / (1.0 - np.cos(angle)))

