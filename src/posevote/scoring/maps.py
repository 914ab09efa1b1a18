"""The test image prepared for the search: phi's maps (Eq. 2) and the voters.

:func:`prepare_test` sorts the test features into voters (those of one
orientation bin in one square merged, :func:`merge_voters`) and tabulates the
test density phi for evenly spaced orientations: at every pixel when the
kernel is narrow, on a coarse grid of ``k x k`` pixel cells when it is wide
(:func:`blurred_points`, :func:`map_grid`), the kernels reading it
bilinearly either way. :func:`restrict_maps` keeps a window of them, and
:func:`scaled_features` divides the features by a scale (one level of a
pyramid). The kernels that read them are in :mod:`posevote.inference.voting`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numba
import numpy as np
from numpy.typing import NDArray

from posevote.features.edges import EdgeFeatures
from posevote.model.kernels import orientation_kernel

_LUT_SIZE = 1024  # orientation-kernel table over [0, pi/2]


#: The most memory (bytes) the test maps of one search may take; a search
#: past it is refused before anything is allocated.
MAX_MAP_BYTES = 4 << 30


@dataclass(frozen=True, kw_only=True, eq=False)
class TestMaps:
    """The test image's features, prepared for voting and scoring.

    Attributes
    ----------
    xy, theta : ndarray
        The test features.
    vote_xy, vote_theta, vote_weight : ndarray
        The voters, sorted by orientation: the test features of one
        orientation bin in one vote cell merged into one, at their mean
        position and orientation, weighted by their number (the votes'
        density is that of the features, at a fraction of the pairs).
    density : ndarray, shape (n_density_bins, GH, GW), float32
        Test density phi (Eq. 2, peak-1 kernels) for ``n_density_bins``
        evenly spaced orientations, on a grid of ``grid x grid`` pixel cells
        (cell ``i`` centred on pixel ``grid * i + (grid - 1) / 2``) and read
        bilinearly (:func:`posevote.scoring.score.phi_at`).
    grid : int
        Pixels per cell of ``density``: 1 for narrow kernels, more for wide
        ones (which a coarse grid resolves, for a ninth of the memory).
    shape : (int, int)
        Image shape (H, W), pixels.
    window : (float, float, float, float)
        ``(u_lo, v_lo, u_hi, v_hi)``, pixels: phi is read where
        ``u_lo <= u < u_hi`` and ``v_lo <= v < v_hi``, and is 0 elsewhere.
    origin : (int, int)
        The pixel ``(u, v)`` of ``density``'s first cell where only a region is tabulated
        (narrow maps: one cell a pixel); ``(0, 0)`` for the whole image.
    lut : ndarray
        Orientation kernel tabulated over ``[0, pi/2]``, 0 below the vote cutoff: a
        training voter pairs with the test voters in the run of orientations where
        it is not.
    position_sigma : float
        Position kernel width of ``density``, pixels.
    chance : float
        Mean of phi over the image's pixels and orientations: the expected
        score of a model dropped at random on the image (its edges explain
        that fraction by chance).
    """

    xy: NDArray[np.float64]
    theta: NDArray[np.float64]
    vote_xy: NDArray[np.float64]
    vote_theta: NDArray[np.float64]
    vote_weight: NDArray[np.float64]
    density: NDArray[np.float32]
    grid: int
    shape: tuple[int, int]
    window: tuple[float, float, float, float]
    lut: NDArray[np.float64]
    position_sigma: float
    chance: float = 0.0
    origin: tuple[int, int] = (0, 0)

    @property
    def frame(self) -> NDArray[np.float64]:
        """The grid as the compiled readers take it: the window in grid units, then
        ``off_u``, ``inv`` and ``off_v``, pixel ``(u, v)`` lying at grid position
        ``((u - off_u) * inv, (v - off_v) * inv)``."""
        off, inv = 0.5 * (self.grid - 1), 1.0 / self.grid
        off_u, off_v = off + self.origin[0], off + self.origin[1]
        u_lo, v_lo, u_hi, v_hi = self.window
        return np.array([(u_lo - off_u) * inv, (v_lo - off_v) * inv, (u_hi - off_u) * inv,
                         (v_hi - off_v) * inv, off_u, inv, off_v])


def prepare_test(features: EdgeFeatures, shape: tuple[int, int], *, position_sigma: float,
                 orientation_kappa: float, edge_spacing: float = 2.0,
                 density_cap: float | None = None, chance_width: float | None = None,
                 vote_bins: int = 16, density_bins: int = 16, vote_cutoff: float = 0.2,
                 region: tuple[int, int, int, int] | None = None) -> TestMaps:
    """Sort the test features by orientation and tabulate phi (Eq. 2).

    Parameters
    ----------
    features : EdgeFeatures
        Test features, image pixels.
    shape : (int, int)
        Image shape (H, W).
    position_sigma, orientation_kappa : float
        Combined kernel widths.
    edge_spacing : float, optional
        Spacing of the test features along edges, pixels. The density is
        divided by that of an isolated straight edge, so that a model
        feature lying on a contour of the image scores about 1.
    density_cap : float, optional
        If given, phi is saturated at this value: a model feature is
        explained by an image edge or not, however dense the edges around
        it (beyond the paper; keeps textured clutter from outvoting
        contours and biasing the scale towards small, dense fits).
    chance_width : float, optional
        If given, the local chance level is subtracted from phi: the mean
        of phi over orientations, blurred at this width (pixels). A model
        feature then scores what an edge explains beyond the edges around
        it, so that a model dropped in dense clutter, or inside the object's
        own texture, no longer scores its chance matches (beyond the paper;
        phi may then be negative).
    vote_bins : int, optional
        Orientation bins: the test features of one bin and one square merge into
        one voter.
    density_bins : int, optional
        Orientations at which phi is tabulated (linear interpolation between).
    vote_cutoff : float, optional
        Pairs whose orientation kernel is below this do not vote (they still
        count in the exact score).
    region : (int, int, int, int), optional
        ``(u_lo, v_lo, u_hi, v_hi)``, pixels (inclusive): tabulate phi there
        only, with the whole image's values, and read it there only (the
        maps' window and ``origin``; 0 elsewhere). For a polish that cannot leave it, at a
        fraction of the work. Narrow kernels (one cell a pixel) without
        ``density_cap`` or ``chance_width`` only; the chance level stays the
        whole image's (:func:`chance_of_points`).

    Returns
    -------
    TestMaps

    Raises
    ------
    ValueError
        If ``region`` is given with a wide kernel, a cap or a chance width, or
        holds no pixel of the image.
    """
    h, w = shape
    k, gh, gw = map_grid(position_sigma, shape)
    if region is not None:
        if k != 1 or density_cap is not None or chance_width is not None:
            raise ValueError("region: only for narrow maps without density_cap or chance_width")
        region = (max(int(region[0]), 0), max(int(region[1]), 0),
                  min(int(region[2]), w - 1), min(int(region[3]), h - 1))
        if region[2] < region[0] or region[3] < region[1]:
            raise ValueError(f"region: {region} holds no pixel of a {w} x {h} image")
    # A region's maps hold the region only.
    need = density_bins * 4 * (gh * gw if region is None
                               else (region[2] - region[0] + 1) * (region[3] - region[1] + 1))
    if need > MAX_MAP_BYTES:
        raise ValueError(f"the test maps of a {w} x {h} image (scaled) take {need / 2**30:.1f} "
                         f"GiB, over the limit of {MAX_MAP_BYTES / 2**30:.0f} GiB; downscale the "
                         "image or narrow SearchOptions.scale_range")
    weight = np.ones(len(features))
    centres = (np.arange(density_bins) + 0.5) * np.pi / density_bins
    # cv2 normalises its Gaussian to unit sum; peak-1 kernels need 2 pi s^2,
    # and an isolated edge sampled every `edge_spacing` pixels then sums to
    # sqrt(2 pi) sigma / spacing, which is brought to 1.
    gain = np.sqrt(2.0 * np.pi) * position_sigma * edge_spacing
    density = orientation_planes(features.xy, features.theta, weight, centres, orientation_kappa,
                                 shape, position_sigma, region=region)
    lut = orientation_kernel(np.linspace(0.0, np.pi / 2, _LUT_SIZE), orientation_kappa)
    if region is None:
        vote_xy, vote_theta, vote_weight = merge_voters(
            features, weight, vote_bins, VOTER_CELLS * vote_cell(position_sigma))
    else:
        # A region's maps are polished on, never voted on: no voters.
        vote_xy, vote_theta, vote_weight = np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    maps = TestMaps(xy=features.xy.copy(), theta=features.theta.copy(), vote_xy=vote_xy,
                    vote_theta=vote_theta, vote_weight=vote_weight,
                    density=density, grid=k, shape=(h, w),
                    window=(0.0, 0.0, float(w - 1), float(h - 1)),
                    lut=np.where(lut >= vote_cutoff, lut, 0.0),
                    position_sigma=float(position_sigma))
    if region is not None:
        u0, v0, u1, v1 = region
        # No cap: the gain alone, in single precision as _saturate applies it.
        density *= np.float32(gain)
        return replace(maps, window=(float(u0), float(v0), float(u1), float(v1)), origin=(u0, v0),
                       chance=chance_of_points(features.xy, features.theta, weight, centres,
                                               orientation_kappa, shape, position_sigma) * gain)
    mean = np.empty(density.shape[1:], dtype=np.float32)
    # On the grid: the cap and the chance level apply to its cells, which the
    # readers interpolate (a cap between cells is the interpolated caps).
    _saturate(density, np.float32(gain), np.float32(-1.0 if density_cap is None else density_cap),
              mean)
    # The planes' sum over orientations, for the chance level, from their mean.
    plane_sum = mean.astype(np.float64) * density_bins
    if chance_width is not None:
        local = chance_plane(mean, k, shape, chance_width)
        _subtract_plane(density, local)
        plane_sum -= local.astype(np.float64) * density_bins
    return replace(maps, chance=window_mean(plane_sum, k, shape, maps.window) / density_bins)


# Two passes over the planes where numpy took five; saturate_reference is
# the numpy they replace.
@numba.njit(cache=True, nogil=True)
def _saturate(density, gain, cap, mean):  # pragma: no cover - compiled
    """``density`` times ``gain``, capped at ``cap`` (none if negative), in place; its
    mean over the planes into ``mean`` (float32, the planes added in order)."""
    n, h, w = density.shape
    mean[:, :] = 0.0
    for b in range(n):
        for r in range(h):
            for c in range(w):
                v = density[b, r, c] * gain
                if cap >= 0.0 and v > cap:
                    v = cap
                density[b, r, c] = v
                mean[r, c] += v
    for r in range(h):
        for c in range(w):
            mean[r, c] /= n


@numba.njit(cache=True, nogil=True)
def _subtract_plane(density, plane):  # pragma: no cover - compiled
    """``plane`` subtracted from every plane of ``density`` in place."""
    n, h, w = density.shape
    for b in range(n):
        for r in range(h):
            for c in range(w):
                density[b, r, c] -= plane[r, c]


def saturate_reference(density: NDArray[np.float32], gain: float, cap: float | None,
                       chance_width: float | None) -> None:
    """Pure-numpy :func:`_saturate` and :func:`_subtract_plane` as :func:`prepare_test`
    applies them, in place (for tests); ``chance_width`` in the planes' cells."""
    density *= np.float32(gain)
    if cap is not None:
        np.minimum(density, np.float32(cap), out=density)
    if chance_width is not None:
        density -= smooth(density.mean(axis=0), chance_width, cv2.BORDER_REFLECT)[None]


def chance_plane(mean: NDArray[np.float32], k: int, shape: tuple[int, int], width: float
                 ) -> NDArray[np.float32]:
    """The local chance level at the grid's cells: ``mean`` (phi's mean over orientations, on
    the grid) blurred at ``width`` pixels.

    Blurred at the pixels, reflected at the image's border (so that its edge
    is not a clearing), and read back at the cells' centres (the pixel before
    the centre for an even ``k``: the plane is far smoother than a pixel).
    """
    if k == 1:
        return smooth(mean, width, cv2.BORDER_REFLECT)
    gh, gw = mean.shape
    pixels = smooth(_refine(mean, k, shape), width, cv2.BORDER_REFLECT)
    pad = cv2.copyMakeBorder(pixels, 0, gh * k - shape[0], 0, gw * k - shape[1],
                             cv2.BORDER_REPLICATE)
    return np.ascontiguousarray(pad[(k - 1) // 2::k, (k - 1) // 2::k])


def _pixel_shares(n_cells: int, k: int, lo: int, hi: int) -> NDArray[np.float64]:
    """Each cell's total share in the bilinear reading of pixels ``lo`` to ``hi`` (inclusive)
    along one axis of a grid of ``k``-pixel cells."""
    out = np.zeros(n_cells)
    if hi < lo:
        return out
    if k == 1:
        out[lo:hi + 1] = 1.0
        return out
    g = np.maximum((np.arange(lo, hi + 1) + 0.5) / k - 0.5, 0.0)
    c0 = g.astype(np.int64)
    f = g - c0
    out += np.bincount(c0, weights=1.0 - f, minlength=n_cells)[:n_cells]
    out += np.bincount(c0 + 1, weights=f, minlength=n_cells)[:n_cells]
    return out


def window_mean(plane: NDArray[np.float64], k: int, shape: tuple[int, int],
                window: tuple[float, float, float, float]) -> float:
    """The mean over the image's pixels of a grid ``plane`` read bilinearly at the window's
    pixels (its edges included) and 0 elsewhere."""
    gh, gw = plane.shape
    cols = _pixel_shares(gw, k, int(window[0]), int(window[2]))
    rows = _pixel_shares(gh, k, int(window[1]), int(window[3]))
    return float(rows @ plane @ cols) / (shape[0] * shape[1])


#: Smoothing runs on a grid coarse enough that the kernel still spans this
#: many of its cells, and is interpolated back (bilinear): a wide kernel then
#: costs a few cells' taps instead of its whole width in pixels. From a
#: 4-pixel kernel on, the bilinear splat on 2-pixel blocks is closer to the
#: sum of Gaussians than points rounded to their pixels.
MIN_SMOOTH_CELLS = 2.0


def _coarse_grid(sigma: float, shape: tuple[int, int]) -> tuple[int, int, int]:
    """Block size ``k`` of the smoothing grid for width ``sigma``, and its shape."""
    k = max(1, int(sigma / MIN_SMOOTH_CELLS))
    return k, -(-shape[0] // k), -(-shape[1] // k)


def _refine(coarse: NDArray[np.float32], k: int, shape: tuple[int, int]) -> NDArray[np.float32]:
    """A coarse grid interpolated back to the pixels (block ``i`` at pixel ``k i + (k - 1) / 2``).

    Bilinear, as the kernels then read the maps: a third of bicubic's cost,
    and as accurate on epfl-cv, epfl-single and COIL (docs/history/METHOD-NOTES.md).
    """
    hs, ws = coarse.shape
    fine = cv2.resize(coarse, (ws * k, hs * k), interpolation=cv2.INTER_LINEAR)
    return np.asarray(fine[:shape[0], :shape[1]])


def map_grid(sigma: float, shape: tuple[int, int]) -> tuple[int, int, int]:
    """The grid :func:`blurred_points` tabulates a kernel of width ``sigma`` on: ``k`` pixels
    a cell, and its shape.

    Pixels for narrow kernels (``k`` = 1); for wide ones the smoothing
    grid and one cell more each way, so that bilinear reading of the last
    pixels stays inside it.
    """
    k, hs, ws = _coarse_grid(sigma, shape)
    return (1, *shape) if k == 1 else (k, hs + 1, ws + 1)


def blurred_points(xy: NDArray[np.float64], values: NDArray[np.float64], shape: tuple[int, int],
                   sigma: float) -> NDArray[np.float32]:
    """Points of mass ``values`` at ``xy`` blurred by a unit-sum Gaussian of width ``sigma``,
    on the grid of :func:`map_grid`.

    Narrow kernels (``sigma < 2 MIN_SMOOTH_CELLS``) blur the points rounded
    to their pixels. Wider ones splat the points bilinearly on a grid of
    ``k x k`` blocks (which keeps their centroid) and blur at ``sigma / k``:
    the cost of a few taps instead of ``6 sigma``, and read bilinearly close
    to the exact sum of Gaussians and, from a 4-pixel kernel on, closer to it
    than the points rounded to their pixels (``tests/scoring/test_maps.py``).
    Outside the image the plane is 0.

    Parameters
    ----------
    xy : ndarray, shape (N, 2)
        Point positions ``(u, v)``, pixels.
    values : ndarray, shape (N,) or (B, N)
        The points' masses; one row per plane for several planes of the
        same points (their places are worked out once).
    shape : (int, int)
        Image shape (H, W).
    sigma : float
        Kernel width, pixels.

    Returns
    -------
    ndarray, shape (GH, GW) or (B, GH, GW), float32
        The blurred points at the grid's cells (the density per pixel).
    """
    rows_of = np.atleast_2d(values)
    k, gh, gw = map_grid(sigma, shape)
    index, fx, fy = _places(xy, k, shape, gh, gw)
    out = np.empty((len(rows_of), gh, gw), dtype=np.float32)
    if k == 1:
        for b, row in enumerate(rows_of):
            plane = np.bincount(index, weights=row, minlength=gh * gw)
            out[b] = cv2.GaussianBlur(plane.astype(np.float32).reshape(gh, gw), (0, 0), sigma,
                                      borderType=cv2.BORDER_CONSTANT)
        return out if np.ndim(values) == 2 else out[0]
    corners = np.concatenate([index, index + 1, index + gw, index + gw + 1])
    ax, ay = 1 - fx, 1 - fy
    width = _splat_width(sigma, k)
    for b, row in enumerate(rows_of):
        # Each block holds k^2 pixels' mass: its blurred value is k^2 the pixels'.
        v = row / (k * k)
        mass = np.concatenate([v * ax * ay, v * fx * ay, v * ax * fy, v * fx * fy])
        splat = np.bincount(corners, weights=mass, minlength=gh * gw).astype(np.float32)
        out[b] = cv2.GaussianBlur(splat.reshape(gh, gw), (0, 0), width,
                                  borderType=cv2.BORDER_CONSTANT)
    return out if np.ndim(values) == 2 else out[0]


def _places(xy: NDArray[np.float64], k: int, shape: tuple[int, int], gh: int, gw: int
            ) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """Where :func:`blurred_points` splats each point: the flat index of its first cell and
    its bilinear fractions (0 when ``k`` is 1: the pixel it rounds to)."""
    h, w = shape
    if k == 1:
        cols = np.clip(np.rint(xy[:, 0]).astype(np.int64), 0, w - 1)
        rows = np.clip(np.rint(xy[:, 1]).astype(np.int64), 0, h - 1)
        zero = np.zeros(len(xy))
        return rows * w + cols, zero, zero
    gx = np.clip((xy[:, 0] + 0.5) / k - 0.5, 0.0, gw - 1.0)
    gy = np.clip((xy[:, 1] + 0.5) / k - 0.5, 0.0, gh - 1.0)
    c0 = np.minimum(gx.astype(np.int64), gw - 2)
    r0 = np.minimum(gy.astype(np.int64), gh - 2)
    return r0 * gw + c0, gx - c0, gy - r0


def _splat_width(sigma: float, k: int) -> float:
    """The blur left after a bilinear splat on ``k``-pixel cells, cells: the splat spreads a
    point by k^2 / 6 (px^2) on average."""
    return float(np.sqrt(sigma**2 - k * k / 6.0) / k)


@numba.njit(cache=True, nogil=True)
def _splat_orientation(index, fx, fy, cos_t, sin_t, weight, centre, kappa, norm, bilinear, gw,
                       out):  # pragma: no cover - compiled
    """Each point's orientation strength in the plane of orientation ``centre``
    (:func:`orientation_kernel` times its weight, over ``norm``) added to ``out`` (the
    plane's cells, zeroed first) at its place, bilinearly or at its cell; ``cos_t`` and
    ``sin_t`` hold the points' cos 2 theta and sin 2 theta."""
    out[:] = 0.0
    # cos 2(theta - c) from the angles' own cosines and sines.
    cos_c = np.cos(2.0 * centre)
    sin_c = np.sin(2.0 * centre)
    for i in range(index.shape[0]):
        v = weight[i] * np.exp(kappa * (cos_t[i] * cos_c + sin_t[i] * sin_c - 1.0)) / norm
        j = index[i]
        if bilinear:
            a, b = fx[i], fy[i]
            out[j] += v * (1.0 - a) * (1.0 - b)
            out[j + 1] += v * a * (1.0 - b)
            out[j + gw] += v * (1.0 - a) * b
            out[j + gw + 1] += v * a * b
        else:
            out[j] += v


def orientation_planes(xy: NDArray[np.float64], theta: NDArray[np.float64],
                       weight: NDArray[np.float64], centres: NDArray[np.float64], kappa: float,
                       shape: tuple[int, int], sigma: float,
                       region: tuple[int, int, int, int] | None = None) -> NDArray[np.float32]:
    """:func:`blurred_points` of the points' orientation strengths, one plane per centre.

    Plane ``b`` holds the points of mass ``weight * orientation_kernel(theta - centres[b],
    kappa)``; each plane's strengths are computed and splatted in one compiled pass, into
    one buffer the planes share (the same planes as :func:`blurred_points` of the
    strengths; writing all the planes point by point missed the cache on large grids).
    With a ``region`` (``(u_lo, v_lo, u_hi, v_hi)`` inside the image, inclusive; narrow
    kernels only) the planes cover the region only, with the whole image's values there:
    the points within the kernel's reach of it are blurred on a tile around it.

    Returns
    -------
    ndarray, shape (len(centres), GH, GW), float32
        With a region: shape (len(centres), v_hi - v_lo + 1, u_hi - u_lo + 1).
    """
    k, gh, gw = map_grid(sigma, shape)
    if region is not None:
        return _region_planes(xy, theta, weight, centres, kappa, shape, sigma, region)
    index, fx, fy = _places(xy, k, shape, gh, gw)
    theta = np.asarray(theta, dtype=np.float64)
    cos_t, sin_t = np.cos(2.0 * theta), np.sin(2.0 * theta)
    weight = np.ascontiguousarray(weight, dtype=np.float64)
    splat = np.empty(gh * gw)
    width = sigma if k == 1 else _splat_width(sigma, k)
    out = np.empty((len(centres), gh, gw), dtype=np.float32)
    for b, centre in enumerate(np.asarray(centres, dtype=np.float64)):
        _splat_orientation(index, fx, fy, cos_t, sin_t, weight, float(centre), float(kappa),
                           float(k * k), k > 1, gw, splat)
        # Blurred straight into its plane (a copy of the plane less).
        cv2.GaussianBlur(splat.astype(np.float32).reshape(gh, gw), (0, 0), width, dst=out[b],
                         borderType=cv2.BORDER_CONSTANT)
    return out


def _blur_taps(sigma: float) -> NDArray[np.float64]:
    """The taps :func:`cv2.GaussianBlur` uses at width ``sigma`` on single precision (its
    size: four sigma each way, odd)."""
    size = int(np.rint(8.0 * sigma + 1.0)) | 1
    return np.asarray(cv2.getGaussianKernel(size, sigma, cv2.CV_32F), dtype=np.float64).ravel()


def _region_planes(xy: NDArray[np.float64], theta: NDArray[np.float64],
                   weight: NDArray[np.float64], centres: NDArray[np.float64], kappa: float,
                   shape: tuple[int, int], sigma: float, region: tuple[int, int, int, int]
                   ) -> NDArray[np.float32]:
    """:func:`orientation_planes` inside ``region`` only (narrow kernels).

    The points are blurred on the tile of the region and the kernel's reach
    around it (cut at the image's border, where the whole image's blur stops
    too), so that the region's pixels sum the same taps of the same points.
    The planes are zeros elsewhere, which the allocator leaves untouched.
    """
    h, w = shape
    reach = len(_blur_taps(sigma)) // 2
    u0, v0, u1, v1 = region
    tu0, tv0 = max(u0 - reach, 0), max(v0 - reach, 0)
    tu1, tv1 = min(u1 + reach, w - 1), min(v1 + reach, h - 1)
    rows, cols = np.divmod(_places(xy, 1, shape, h, w)[0], w)
    near = (cols >= tu0) & (cols <= tu1) & (rows >= tv0) & (rows <= tv1)
    tile = orientation_planes(np.stack([cols[near] - tu0, rows[near] - tv0], axis=1).astype(
        np.float64), np.asarray(theta)[near], np.asarray(weight)[near], centres, kappa,
        (tv1 - tv0 + 1, tu1 - tu0 + 1), sigma)
    return np.ascontiguousarray(tile[:, v0 - tv0:v1 - tv0 + 1, u0 - tu0:u1 - tu0 + 1])


def chance_of_points(xy: NDArray[np.float64], theta: NDArray[np.float64],
                     weight: NDArray[np.float64], centres: NDArray[np.float64], kappa: float,
                     shape: tuple[int, int], sigma: float) -> float:
    """The mean over the image's pixels and planes of :func:`orientation_planes` (narrow
    kernels), from the points alone.

    The blur keeps each point's mass but for the taps past the image's
    border: each point counts its orientation strengths times the share of
    the kernel that lands inside the image (the maps' chance level without
    tabulating the whole image).
    """
    h, w = shape
    taps = _blur_taps(sigma)
    reach = len(taps) // 2
    # Share of the kernel inside [0, n) for a point at each pixel.
    def inside(n: int) -> NDArray[np.float64]:
        padded = np.convolve(np.ones(n), taps)
        return np.asarray(padded[reach:reach + n])
    # The pixels the splat rounds the points to.
    rows, cols = np.divmod(_places(xy, 1, shape, h, w)[0], w)
    theta = np.asarray(theta, dtype=np.float64)
    centres = np.asarray(centres, dtype=np.float64)
    # cos 2(theta - c) from the angles' own cosines and sines, as the splat has it.
    cos_c = np.outer(np.cos(2.0 * theta), np.cos(2.0 * centres))
    cos_c += np.outer(np.sin(2.0 * theta), np.sin(2.0 * centres))
    cos_c -= 1.0
    cos_c *= kappa
    strength = np.exp(cos_c, out=cos_c).sum(axis=1)
    mass = np.asarray(weight) * inside(w)[cols] * inside(h)[rows]
    return float(mass @ strength) / (len(centres) * h * w)


def smooth(plane: NDArray[np.float32], sigma: float, border: int) -> NDArray[np.float32]:
    """Gaussian blur of a smooth ``plane`` at width ``sigma``, on a coarser grid when it allows.

    The plane is averaged over ``k x k`` blocks (``k`` as
    :func:`blurred_points` chooses it), blurred at ``sigma / k`` and
    interpolated back; the averaging moves detail by up to ``k / 2``
    pixels, which a plane already smooth at that scale does not have.

    Parameters
    ----------
    plane : ndarray, shape (H, W), float32
    sigma : float
        Kernel width, pixels.
    border : int
        OpenCV border type (``cv2.BORDER_CONSTANT`` or ``cv2.BORDER_REFLECT``).

    Returns
    -------
    ndarray, shape (H, W), float32
    """
    k, hs, ws = _coarse_grid(sigma, plane.shape)
    if k == 1:
        return np.asarray(cv2.GaussianBlur(plane, (0, 0), sigma, borderType=border))
    h, w = plane.shape
    padded = cv2.copyMakeBorder(plane, 0, hs * k - h, 0, ws * k - w, border, value=0.0)
    coarse = cv2.resize(padded, (ws, hs), interpolation=cv2.INTER_AREA)
    blurred = np.asarray(cv2.GaussianBlur(coarse, (0, 0), sigma / k, borderType=border),
                         dtype=np.float32)
    return _refine(blurred, k, plane.shape)


#: The test features merged into one voter lie in a square of this many vote cells.
VOTER_CELLS = 2.0


def vote_cell(position_sigma: float) -> float:
    """The vote grid's cell for maps of kernel width ``position_sigma``: two-thirds of it, >= 1.5 px.

    Votes are smoothed at ``position_sigma`` (1.5 cells), so that the grid
    resolves their peaks without a cell per pixel.
    """
    return max(1.5, position_sigma / 1.5)


def merge_voters(features: EdgeFeatures, weight: NDArray[np.float64], n_bins: int, cell: float
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The features of each orientation bin and ``cell``-sized square merged into one voter.

    A voter stands at its features' weighted mean position and orientation,
    with their total weight; its bilinear vote, smoothed over 1.5 cells, is
    theirs but for the spread inside one cell.

    Returns
    -------
    xy, theta, weight : ndarray
        The voters, sorted by orientation (a voter's mean orientation stays in its bin).
    """
    if len(features) == 0:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    bins = np.minimum((features.theta / np.pi * n_bins).astype(np.int64), n_bins - 1)
    cells = np.floor(features.xy / cell).astype(np.int64)
    cells -= cells.min(axis=0)
    nx, ny = int(cells[:, 0].max()) + 1, int(cells[:, 1].max()) + 1
    key = (bins * ny + cells[:, 1]) * nx + cells[:, 0]
    _, group = np.unique(key, return_inverse=True)
    total = np.bincount(group, weights=weight).astype(np.float64)
    safe = np.where(total > 0, total, 1.0)
    xy = np.stack([np.bincount(group, weights=weight * features.xy[:, k]) / safe
                   for k in range(2)], axis=1)
    theta = np.bincount(group, weights=weight * features.theta) / safe
    # By orientation: a training voter's pairs are then one run of them, the
    # orientations within the table's reach of its own.
    order = np.argsort(theta, kind="stable")
    return xy[order], theta[order], total[order]


def restrict_maps(maps: TestMaps, lo: NDArray[np.float64], hi: NDArray[np.float64]
                  ) -> TestMaps:
    """The maps of the test features inside the rectangle ``lo``-``hi`` only.

    Features outside are dropped and phi is read inside the rectangle only
    (0 outside), so that the search finds the object inside it (what
    preparing the maps again from those features would give, but for the
    kernel's spill across the border). The planes are shared, not copied.
    The chance level is that of the restricted phi.

    Parameters
    ----------
    maps : TestMaps
        Maps of the whole image.
    lo, hi : ndarray, shape (2,)
        Corners ``(u, v)`` of the rectangle, in the maps' pixels.

    Returns
    -------
    TestMaps

    Raises
    ------
    ValueError
        If ``maps`` tabulate a region only (:func:`prepare_test`).
    """
    if maps.density.shape[1:] != map_grid(maps.position_sigma, maps.shape)[1:]:
        raise ValueError("restrict_maps: the maps tabulate a region only; prepare the whole "
                         "image's")
    inside = np.all((maps.xy >= lo) & (maps.xy <= hi), axis=1)
    voting = np.all((maps.vote_xy >= lo) & (maps.vote_xy <= hi), axis=1)
    u_lo, v_lo, u_hi, v_hi = maps.window
    window = (max(float(np.floor(lo[0])), u_lo), max(float(np.floor(lo[1])), v_lo),
              min(float(np.ceil(hi[0])), u_hi), min(float(np.ceil(hi[1])), v_hi))
    # The planes' sum over orientations, on the cells the window reads only.
    k, (n_planes, gh, gw) = maps.grid, maps.density.shape
    r0, c0 = (max(int((bound - 0.5 * (k - 1)) // k), 0) for bound in window[1::-1])
    r1, c1 = (min(int((bound - 0.5 * (k - 1)) // k) + 2, n) for bound, n in
              ((window[3], gh), (window[2], gw)))
    plane_sum = np.zeros((gh, gw))
    if r1 > r0 and c1 > c0:
        plane_sum[r0:r1, c0:c1] = maps.density[:, r0:r1, c0:c1].sum(axis=0, dtype=np.float64)
    return replace(maps, xy=maps.xy[inside], theta=maps.theta[inside],
                   vote_xy=maps.vote_xy[voting], vote_theta=maps.vote_theta[voting],
                   vote_weight=maps.vote_weight[voting], window=window,
                   chance=window_mean(plane_sum, k, maps.shape, window) / n_planes)


def scaled_features(features: EdgeFeatures, shape: tuple[int, int], scale: float
                    ) -> tuple[EdgeFeatures, tuple[int, int]]:
    """Test features and image shape divided by ``scale`` (one level of a pyramid).

    Searching the model at scale 1 in these features is searching it at
    ``scale`` in the image, with every kernel width multiplied by ``scale``:
    the position kernel is then fixed in object units, so that small scales
    do not enjoy a wider relative tolerance than large ones.
    """
    h, w = shape
    out_shape = (max(1, int(np.ceil(h / scale))), max(1, int(np.ceil(w / scale))))
    return EdgeFeatures(xy=features.xy / scale, theta=features.theta), out_shape
