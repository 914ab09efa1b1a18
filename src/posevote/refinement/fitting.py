"""Continuous refinement by local distribution fitting (Sec. II-B, Fig. 1 right).

Around each main peak of the probes, an isotropic distribution is fitted to
the probe scores by non-linear least squares: a peaked kernel on the viewing
direction, a von Mises on the in-plane angle and a Gaussian on log-scale,
times an amplitude, plus a floor::

    f(w) = b + A * exp(-k_v (1 - d(w1) . mu_v)^g + k_a (cos(alpha - mu_a) - 1)
                        - (log s - mu_s)^2 / (2 s_s^2))

The fitted means are the estimate: this is what takes accuracy below the
spacing of the training views. With ``g = 1`` the viewpoint term is the
paper's von Mises-Fisher kernel, rounded at its peak. The probe scores of
edge features fall off more sharply than that (an edge moves linearly with
the rotation), and a rounded kernel fitted to a sharp profile sampled at the
training views pulls its mean toward the best sampled view; ``g = 0.5``
decays about linearly with the angle (``1 - cos t = 2 sin^2(t / 2)``), a
cusp. The default ``g`` (:data:`VIEW_SHAPE`) was chosen on rendered
turntables, where that pull vanishes (``benchmarks/tune_rendered.py``,
docs/DEFAULTS.md).

Dimensions with fewer than three distinct probed values in the
neighbourhood are not fitted (the probe value is kept); widths are bounded
to four grid steps, and an in-plane or scale mean that ends on its bound (a
flat profile) is replaced by the best probe's value.
"""

from __future__ import annotations

import statistics

import numba
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from posevote.geometry import angle_difference, rotate_points, viewing_direction, wrap_angle
from posevote.inference.probes import ProbeSet
from posevote.results import Hypothesis

#: Relative tolerance of the fit: scipy's default (1e-8) spends half of its
#: evaluations moving the means by a hundredth of a degree
#: (benchmarks/fit_tolerance.py; docs/DEFAULTS.md).
FIT_TOLERANCE = 1e-4

#: Exponent of the viewpoint term (module docstring): where the estimate's pull toward
#: the nearest training view vanishes on rendered turntables with the COIL protocol's
#: geometry (benchmarks/tune_rendered.py; docs/DEFAULTS.md).
VIEW_SHAPE = 0.6

#: Viewpoints within this many probe spacings of a mode take part in its fit
#: (and in the local refinement's profile): two neighbours on either side.
FIT_RADIUS_STEPS = 2.5

#: Most evaluations of the fitted distribution in one fit.
_MAX_EVALUATIONS = 100

#: A step past a bound goes this share of the way to it (the kernel's docstring).
_TO_BOUND = 0.99


def find_modes(probes: ProbeSet, *, max_modes: int = 3, min_separation: float = np.radians(30.0),
               relative_floor: float = 0.5) -> list[int]:
    """Viewpoints that are local maxima of the score profile, best first.

    The profile is the best score over in-plane angle and scale at each
    viewpoint. A viewpoint is a mode if no viewpoint within
    ``min_separation`` scores higher, and its score is at least
    ``relative_floor`` times the best.

    Returns
    -------
    list of int
        Indices into the probed viewpoints.
    """
    profile = probes.score.max(axis=(1, 2))
    if profile.size == 0 or profile.max() <= 0:
        return []
    directions = probes.directions
    cos_sep = np.cos(min_separation)
    modes: list[int] = []
    for v in np.argsort(-profile, kind="stable"):
        if profile[v] < relative_floor * profile.max() or len(modes) >= max_modes:
            break
        near = directions @ directions[v] >= cos_sep
        if profile[v] >= profile[near].max() and all(
                directions[m] @ directions[v] < cos_sep for m in modes):
            modes.append(int(v))
    return modes


def neighbour_viewpoints(probes: ProbeSet, viewpoint: int, *, radius_steps: float
                         ) -> NDArray[np.intp]:
    """Probed viewpoints within ``radius_steps`` probe spacings of ``viewpoint``."""
    d = probes.directions
    return np.flatnonzero(d @ d[viewpoint] >= np.cos(radius_steps * probes.spacing))


#: On a grid over the sphere, the profile's peak is read from the viewpoints within
#: this many probe spacings of the best: the best and its nearest neighbours along
#: azimuth and elevation (:func:`peak_viewpoint`, docs/DEFAULTS.md).
PEAK_RADIUS_STEPS = 1.5


def peak_viewpoint(probes: ProbeSet, viewpoint: int) -> tuple[float, float] | None:
    """The viewpoint at the peak of a quadratic through a 2-D profile's best view and its
    nearest neighbours (beyond the paper).

    The scores of the viewpoints within :data:`PEAK_RADIUS_STEPS` probe spacings
    of ``viewpoint`` are fitted, by least squares, with a quadratic in the
    azimuth (times the cosine of the elevation) and the elevation without their
    cross term: along each axis, the parabola through the best view and its two
    neighbours. On a sphere of training views the isotropic peaked kernel of
    :func:`refine_mode`, fitted over a wider neighbourhood of views spaced
    unevenly around the best one, pulls the estimate away from the nearest
    training view; the parabola does not (docs/DEFAULTS.md). The peak stays
    within one spacing of the best view.

    Parameters
    ----------
    probes : ProbeSet
        A profile over viewpoints at several elevations (one in-plane angle and
        scale a viewpoint; the best score over them is read).
    viewpoint : int
        The best viewpoint.

    Returns
    -------
    (float, float) or None
        Azimuth and elevation, radians; None where the neighbours do not
        determine a peak (too few, at one elevation only, or the quadratic not
        concave).
    """
    spacing = probes.spacing
    near = neighbour_viewpoints(probes, viewpoint, radius_steps=PEAK_RADIUS_STEPS)
    az0, el0 = float(probes.azimuth[viewpoint]), float(probes.elevation[viewpoint])
    # Offsets in probe spacings, the azimuth's along the circle of its elevation.
    x = np.column_stack([angle_difference(probes.azimuth[near], az0) * np.cos(el0),
                         probes.elevation[near] - el0]) / spacing
    design = np.column_stack([np.ones(len(near)), x, x * x])
    if len(near) < design.shape[1] or np.linalg.matrix_rank(design) < design.shape[1]:
        return None
    score = probes.score[near].reshape(len(near), -1).max(axis=1)
    c = np.linalg.lstsq(design, score, rcond=None)[0]
    if not (c[3] < 0 and c[4] < 0):
        return None
    peak = -c[1:3] / (2.0 * c[3:5])
    peak /= max(float(np.linalg.norm(peak)), 1.0)
    return (float(wrap_angle(az0 + peak[0] * spacing / max(np.cos(el0), 1e-6))),
            float(el0 + peak[1] * spacing))


def _view_params(p: NDArray[np.float64], fixed_el: float | None) -> tuple[float, float, float]:
    """(mean azimuth, mean elevation, concentration) from the fitted view parameters."""
    if fixed_el is not None:
        return float(p[0]), fixed_el, float(p[1])
    return float(p[0]), float(p[1]), float(p[2])


def _model(params: NDArray[np.float64], layout: dict, X: dict
           ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Values of the fitted distribution at the probes, and its Jacobian."""
    b, amp = params[0], params[1]
    n = X["dir"].shape[0]
    expo = np.zeros(n)
    parts: list[tuple[str, int]] = []
    i = 2
    fixed_el = layout["fixed_elevation"]
    shape = layout["view_shape"]
    n_view = 2 if fixed_el is not None else 3
    if layout["view"]:
        parts.append(("view", i))
        mu_az, mu_el, k_v = _view_params(params[i:i + n_view], fixed_el)
        # distance to the mean direction, floored so its power's slope is finite
        one_g = np.maximum(1.0 - X["dir"] @ viewing_direction(mu_az, mu_el), 1e-12)
        powered = one_g ** shape
        expo -= k_v * powered
        i += n_view
    if layout["inplane"]:
        parts.append(("inplane", i))
        mu_a, k_a = params[i:i + 2]
        expo += k_a * (np.cos(X["inplane"] - mu_a) - 1.0)
        i += 2
    if layout["scale"]:
        parts.append(("scale", i))
        mu_s, s_s = params[i:i + 2]
        expo -= (X["logs"] - mu_s) ** 2 / (2.0 * s_s * s_s)
        i += 2
    e = np.exp(expo)
    jac = np.empty((n, i))
    jac[:, 0] = 1.0
    jac[:, 1] = e
    ae = amp * e
    for name, j in parts:
        if name == "view":
            mu_az, mu_el, k_v = _view_params(params[j:j + n_view], fixed_el)
            ca, sa = np.cos(-mu_az), np.sin(-mu_az)
            ce, se = np.cos(mu_el), np.sin(mu_el)
            d_az = np.array([ce * sa, -ce * ca, 0.0])
            slope = shape * powered / one_g
            jac[:, j] = ae * k_v * slope * (X["dir"] @ d_az)
            if fixed_el is None:
                d_el = np.array([-se * ca, -se * sa, ce])
                jac[:, j + 1] = ae * k_v * slope * (X["dir"] @ d_el)
            jac[:, j + n_view - 1] = -ae * powered
        elif name == "inplane":
            mu_a, k_a = params[j:j + 2]
            jac[:, j] = ae * k_a * np.sin(X["inplane"] - mu_a)
            jac[:, j + 1] = ae * (np.cos(X["inplane"] - mu_a) - 1.0)
        else:
            mu_s, s_s = params[j:j + 2]
            r = X["logs"] - mu_s
            jac[:, j] = ae * r / s_s**2
            jac[:, j + 1] = ae * r * r / s_s**3
    return b + amp * e, jac


@numba.njit(cache=True, nogil=True)
def _model_kernel(params, dirs, inplane, logs, has_view, has_inplane, has_scale, fixed_el, shape,
                  f, jac):  # pragma: no cover - compiled
    """:func:`_model` into ``f`` and ``jac``; ``fixed_el`` NaN fits the elevation."""
    turntable = not np.isnan(fixed_el)
    n_view = 2 if turntable else 3
    j_in = 2 + (n_view if has_view else 0)
    j_sc = j_in + (2 if has_inplane else 0)
    b = params[0]
    amp = params[1]
    mu = np.zeros(3)
    d_az = np.zeros(3)
    d_el = np.zeros(3)
    k_v = mu_a = k_a = mu_s = s_s = 0.0
    if has_view:
        mu_az = params[2]
        mu_el = fixed_el if turntable else params[3]
        k_v = params[2 + n_view - 1]
        ca, sa = np.cos(-mu_az), np.sin(-mu_az)
        ce, se = np.cos(mu_el), np.sin(mu_el)
        mu[0], mu[1], mu[2] = ce * ca, ce * sa, se
        d_az[0], d_az[1] = ce * sa, -ce * ca
        d_el[0], d_el[1], d_el[2] = -se * ca, -se * sa, ce
    if has_inplane:
        mu_a, k_a = params[j_in], params[j_in + 1]
    if has_scale:
        mu_s, s_s = params[j_sc], params[j_sc + 1]
    for k in range(dirs.shape[0]):
        expo = 0.0
        one_g = powered = c = s = r = 0.0
        if has_view:
            dot = dirs[k, 0] * mu[0] + dirs[k, 1] * mu[1] + dirs[k, 2] * mu[2]
            one_g = max(1.0 - dot, 1e-12)
            powered = one_g ** shape
            expo -= k_v * powered
        if has_inplane:
            c = np.cos(inplane[k] - mu_a)
            s = np.sin(inplane[k] - mu_a)
            expo += k_a * (c - 1.0)
        if has_scale:
            r = logs[k] - mu_s
            expo -= r * r / (2.0 * s_s * s_s)
        e = np.exp(expo)
        ae = amp * e
        f[k] = b + ae
        jac[k, 0] = 1.0
        jac[k, 1] = e
        if has_view:
            slope = ae * k_v * shape * powered / one_g
            jac[k, 2] = slope * (dirs[k, 0] * d_az[0] + dirs[k, 1] * d_az[1])
            if not turntable:
                jac[k, 3] = slope * (dirs[k, 0] * d_el[0] + dirs[k, 1] * d_el[1]
                                     + dirs[k, 2] * d_el[2])
            jac[k, 2 + n_view - 1] = -ae * powered
        if has_inplane:
            jac[k, j_in] = ae * k_a * s
            jac[k, j_in + 1] = ae * (c - 1.0)
        if has_scale:
            jac[k, j_sc] = ae * r / (s_s * s_s)
            jac[k, j_sc + 1] = ae * r * r / (s_s * s_s * s_s)


@numba.njit(cache=True, nogil=True)
def _least_squares_kernel(p0, lo, hi, dirs, inplane, logs, y, has_view, has_inplane, has_scale,
                          fixed_el, shape, tol, max_nfev):  # pragma: no cover - compiled
    """Bounded Levenberg-Marquardt on :func:`_model_kernel`'s residuals.

    The damping is scaled by the Jacobian's column norms (scipy's
    ``x_scale="jac"``); a parameter on a bound that the gradient pushes
    outward is held there; a step past a bound stops just short of it (an
    amplitude clipped to 0 would flatten the model and stop the fit on a
    zero gradient). Stops as scipy's
    ``least_squares`` does: the cost falls by less than ``tol`` of itself
    (ftol), the step is below ``tol`` of the parameters (xtol), or the
    gradient is nearly orthogonal to the residuals (gtol). Returns the
    parameters and the evaluations spent.
    """
    m = p0.shape[0]
    n = y.shape[0]
    p = p0.copy()
    f = np.empty(n)
    jac = np.empty((n, m))
    f_new = np.empty(n)
    jac_new = np.empty((n, m))
    _model_kernel(p, dirs, inplane, logs, has_view, has_inplane, has_scale, fixed_el, shape, f,
                  jac)
    r = f - y
    cost = 0.5 * np.dot(r, r)
    nfev = 1
    d2 = np.zeros(m)
    lam = 1e-3
    nu = 2.0
    while nfev < max_nfev and np.isfinite(cost):
        a = jac.T @ jac
        g = jac.T @ r
        rnorm = np.sqrt(2.0 * cost)
        worst = 0.0
        for i in range(m):
            d2[i] = max(d2[i], a[i, i])
            if a[i, i] > 0.0 and rnorm > 0.0:
                worst = max(worst, abs(g[i]) / (np.sqrt(a[i, i]) * rnorm))
        if worst <= tol:
            break
        while nfev < max_nfev:
            mat = a.copy()
            rhs = -g
            for i in range(m):
                mat[i, i] += lam * (d2[i] if d2[i] > 0.0 else 1.0)
                if (p[i] <= lo[i] and g[i] > 0.0) or (p[i] >= hi[i] and g[i] < 0.0):
                    mat[i, :] = 0.0
                    mat[:, i] = 0.0
                    mat[i, i] = 1.0
                    rhs[i] = 0.0
            delta = np.linalg.solve(mat, rhs)
            p_new = p + delta
            for i in range(m):
                if p_new[i] < lo[i]:
                    p_new[i] = p[i] + _TO_BOUND * (lo[i] - p[i])
                elif p_new[i] > hi[i]:
                    p_new[i] = p[i] + _TO_BOUND * (hi[i] - p[i])
            step = p_new - p
            _model_kernel(p_new, dirs, inplane, logs, has_view, has_inplane, has_scale, fixed_el,
                          shape, f_new, jac_new)
            nfev += 1
            r_new = f_new - y
            cost_new = 0.5 * np.dot(r_new, r_new)
            predicted = -(np.dot(g, step) + 0.5 * np.dot(step, a @ step))
            small_step = np.sqrt(np.dot(step, step)) < tol * (tol + np.sqrt(np.dot(p, p)))
            if np.isfinite(cost_new) and cost_new < cost:
                rho = (cost - cost_new) / predicted if predicted > 0.0 else 1.0
                converged = (cost - cost_new < tol * cost and rho > 0.25) or small_step
                p = p_new
                f, f_new = f_new, f
                jac, jac_new = jac_new, jac
                r = r_new
                cost = cost_new
                lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                if converged:
                    return p, nfev
                break
            lam *= nu
            nu *= 2.0
            if small_step or lam > 1e16:
                return p, nfev
    return p, nfev


def refine_mode(probes: ProbeSet, viewpoint: int, *, radius_steps: float = 2.5, span: int = 2,
                fit: bool = True, tolerance: float = FIT_TOLERANCE,
                view_shape: float = VIEW_SHAPE) -> Hypothesis:
    """Continuous pose estimate of one mode (Sec. II-B).

    Parameters
    ----------
    probes : ProbeSet
        The probes of p(w).
    viewpoint : int
        Index of the mode's best viewpoint (from :func:`find_modes`).
    radius_steps : float, optional
        Viewpoints within this many probe spacings of the mode take part.
    span : int, optional
        In-plane and scale steps on each side of the best one that take part.
    fit : bool, optional
        False returns the best discrete probe (the ablation "without fitting").
    tolerance : float, optional
        Relative tolerance of the least-squares fit (its ``ftol``, ``xtol``
        and ``gtol``, as :func:`scipy.optimize.least_squares` reads them).
    view_shape : float, optional
        Exponent ``g`` of the viewpoint term (module docstring): 1 is the
        von Mises-Fisher kernel, smaller values a sharper peak.

    Returns
    -------
    Hypothesis
    """
    a_best, s_best = np.unravel_index(np.argmax(probes.score[viewpoint]), probes.score.shape[1:])
    best_score = float(probes.score[viewpoint, a_best, s_best])
    az, el = probes.azimuth[viewpoint], probes.elevation[viewpoint]
    alpha, scale = probes.inplane[a_best], probes.scale[s_best]
    position = probes.translation[viewpoint, a_best, s_best]
    refined = False
    if fit and best_score > 0:
        fitted = _fit(probes, viewpoint, int(a_best), int(s_best), radius_steps, span,
                      tolerance, view_shape)
        if fitted is not None:
            az, el, alpha, scale = fitted
            refined = True
    box_wh = _box_at(probes, az, el)
    return Hypothesis(
        azimuth=float(wrap_angle(az)), elevation=float(el), inplane=float(alpha),
        scale=float(scale), position=(float(position[0]), float(position[1])),
        box=box_from_pose(position, box_wh * scale, alpha), score=best_score, refined=refined)


def _fit(probes: ProbeSet, v0: int, a0: int, s0: int, radius_steps: float, span: int,
         tolerance: float, view_shape: float) -> tuple[float, float, float, float] | None:
    directions = probes.directions
    step_v = probes.spacing
    views = neighbour_viewpoints(probes, v0, radius_steps=radius_steps)
    a_idx = np.arange(max(0, a0 - span), min(len(probes.inplane), a0 + span + 1))
    s_idx = np.arange(max(0, s0 - span), min(len(probes.scale), s0 + span + 1))
    vv, aa, ss = np.meshgrid(views, a_idx, s_idx, indexing="ij")
    # A ranking search's unprobed probes hold 0 without a score: left out of the fit.
    if probes.probed is not None:
        kept = probes.probed[vv, aa, ss]
        vv, aa, ss = vv[kept], aa[kept], ss[kept]
    y = probes.score[vv, aa, ss].ravel()
    X = {"dir": directions[vv.ravel()], "inplane": probes.inplane[aa.ravel()],
         "logs": np.log(probes.scale[ss.ravel()])}
    layout = {"view": len(views) >= 3, "inplane": len(a_idx) >= 3, "scale": len(s_idx) >= 3,
              "fixed_elevation": float(probes.elevation[v0]) if probes.turntable else None,
              "view_shape": view_shape}
    if not (layout["view"] or layout["inplane"] or layout["scale"]):
        return None
    top = float(y.max())
    p0 = [float(y.min()), max(top - float(y.min()), 1e-6)]
    lo = [0.0, 0.0]
    hi = [top, 4.0 * top + 1e-6]
    az0, el0 = probes.azimuth[v0], probes.elevation[v0]
    if layout["view"]:
        k0 = np.log(2.0) / (1.0 - np.cos(step_v)) ** view_shape
        if probes.turntable:
            p0 += [az0, k0]
            lo += [az0 - step_v, k0 / 16.0]
            hi += [az0 + step_v, k0 * 50.0]
        else:
            p0 += [az0, el0, k0]
            lo += [az0 - step_v, el0 - step_v, k0 / 16.0]
            hi += [az0 + step_v, el0 + step_v, k0 * 50.0]
    if layout["inplane"]:
        step_a = statistics.median(np.diff(probes.inplane).tolist())
        k0 = np.log(2.0) / (1.0 - np.cos(step_a))
        mu0 = probes.inplane[a0]
        p0 += [mu0, k0]
        lo += [mu0 - step_a, k0 / 16.0]
        hi += [mu0 + step_a, k0 * 50.0]
    if layout["scale"]:
        step_s = statistics.median(np.diff(np.log(probes.scale)).tolist())
        mu0 = float(np.log(probes.scale[s0]))
        p0 += [mu0, step_s]
        lo += [mu0 - step_s, step_s / 20.0]
        hi += [mu0 + step_s, step_s * 4.0]
    p0 = np.clip(np.asarray(p0, dtype=float), lo, hi)
    fit = solve_fit(p0, np.asarray(lo, dtype=float), np.asarray(hi, dtype=float), X, y, layout,
                    tolerance)
    if fit is None:
        return None
    # An in-plane or scale mean that ends on its bound (a flat profile) is not
    # trusted: that dimension keeps the best probe's value. Viewpoint means
    # may legitimately reach the bound (the truth halfway between views).
    p = fit.copy()
    n_view = (2 if probes.turntable else 3) if layout["view"] else 0
    # np.isclose's test, written out (a tenth of a fit's time in its own checks).
    on_bound = (np.abs(p - lo) <= 1e-8 + 1e-5 * np.abs(lo)) | (
        np.abs(p - hi) <= 1e-8 + 1e-5 * np.abs(hi))
    on_bound[:2 + n_view] = False
    p[on_bound] = p0[on_bound]
    i = 2
    az, el = az0, el0
    alpha, scale = probes.inplane[a0], probes.scale[s0]
    if layout["view"]:
        n_view = 2 if probes.turntable else 3
        az, el, _ = _view_params(p[i:i + n_view], layout["fixed_elevation"])
        i += n_view
    if layout["inplane"]:
        alpha = p[i]
        i += 2
    if layout["scale"]:
        scale = float(np.exp(p[i]))
    return float(az), float(el), float(alpha), float(scale)


def solve_fit(p0: NDArray[np.float64], lo: NDArray[np.float64], hi: NDArray[np.float64], X: dict,
              y: NDArray[np.float64], layout: dict, tolerance: float
              ) -> NDArray[np.float64] | None:
    """Bounded least-squares parameters of :func:`_model` to ``y`` (compiled), or None."""
    if not np.all(np.isfinite(y)):
        return None
    fixed = layout["fixed_elevation"]
    try:
        p, _ = _least_squares_kernel(
            p0, lo, hi, np.ascontiguousarray(X["dir"], dtype=np.float64),
            np.ascontiguousarray(X["inplane"], dtype=np.float64),
            np.ascontiguousarray(X["logs"], dtype=np.float64),
            np.ascontiguousarray(y, dtype=np.float64), layout["view"], layout["inplane"],
            layout["scale"], np.nan if fixed is None else fixed, float(layout["view_shape"]),
            float(tolerance), _MAX_EVALUATIONS)
    except np.linalg.LinAlgError:  # a damped system singular: a non-finite Jacobian
        return None
    return p if np.all(np.isfinite(p)) else None


def solve_fit_reference(p0: NDArray[np.float64], lo: NDArray[np.float64], hi: NDArray[np.float64],
                        X: dict, y: NDArray[np.float64], layout: dict, tolerance: float
                        ) -> NDArray[np.float64] | None:
    """:func:`solve_fit` by scipy's trust-region reflective least squares (the reference)."""
    try:
        memo: dict[bytes, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}

        def evaluate(p: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
            # scipy asks for the residuals and the Jacobian at the same point
            # separately; compute both once.
            key = p.tobytes()
            if key not in memo:
                memo.clear()
                memo[key] = _model(p, layout, X)
            return memo[key]

        result = least_squares(lambda p: evaluate(p)[0] - y, p0, jac=lambda p: evaluate(p)[1],
                               bounds=(lo, hi), method="trf", max_nfev=_MAX_EVALUATIONS,
                               x_scale="jac", ftol=tolerance, xtol=tolerance, gtol=tolerance)
    except (ValueError, np.linalg.LinAlgError):
        return None
    # Status 0 (evaluation budget spent) still leaves a usable, bounded fit.
    if result.status < 0 or not np.all(np.isfinite(result.x)):
        return None
    return np.asarray(result.x, dtype=np.float64)


def _box_at(probes: ProbeSet, az: float, el: float) -> NDArray[np.float64]:
    """Box size at a continuous viewpoint: blend of the two nearest probes."""
    d = probes.directions @ viewing_direction(az, el)
    near = np.argsort(-d)[:2]
    ang = np.arccos(np.clip(d[near], -1, 1)) + 1e-9
    weights = 1.0 / ang
    return (probes.box[near] * weights[:, None]).sum(axis=0) / weights.sum()


def box_from_pose(position: NDArray[np.float64], size: NDArray[np.float64], alpha: float
         ) -> tuple[float, float, float, float]:
    """Axis-aligned box of a ``size`` rectangle centred on ``position``, turned by ``alpha``."""
    w, h = size
    corners = rotate_points(np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) / 2.0, alpha)
    lo = corners.min(axis=0) + position
    extent = corners.max(axis=0) - corners.min(axis=0)
    return float(lo[0]), float(lo[1]), float(extent[0]), float(extent[1])

