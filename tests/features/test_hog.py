"""HOG: the compiled kernel agrees with scikit-image's."""

from __future__ import annotations

import numpy as np

from posevote.features.hog import hog, hog_reference


def test_hog_kernel_agrees_with_scikit_image(draw):
    rng = np.random.default_rng(3)
    crops = [rng.random((48, 112)), np.round(rng.random((48, 48)) * 3) / 3,
             np.zeros((16, 24)), draw(np.radians(70.0), size=96)[:96, :88],
             np.tile(np.linspace(0.0, 1.0, 40), (32, 1))]
    for crop in crops:
        got, want = hog(crop), hog_reference(crop)
        assert got.dtype == np.float32 and got.shape == want.shape
        np.testing.assert_allclose(got, want, atol=1e-5)
