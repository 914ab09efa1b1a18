"""Kernels of the densities (Eqs. 1-3)."""

import numpy as np
import pytest

from posevote.model.kernels import kappa_for_width, orientation_kernel


def test_orientation_kernel_is_undirected_and_peaks_at_one():
    assert orientation_kernel(0.0, 5.0) == pytest.approx(1.0)
    assert orientation_kernel(np.pi, 5.0) == pytest.approx(1.0)
    assert orientation_kernel(np.pi / 2, 5.0) < 1e-4
    k = kappa_for_width(0.2, doubled=True)
    assert orientation_kernel(0.2, k) == pytest.approx(0.5)
