"""The training density psi (Eq. 1), the test density phi (Eq. 2) and p(w) (Eq. 3).

A :class:`PoseModel` stores the training pairs ``(w_i, x_i)``: every edge
feature of every training view, object-centred, scale-normalised and upright,
with the pose of its view and its weight ``wt_i`` (Eq. 4).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from posevote.features.edges import EdgeFeatures, normalize_features
from posevote.geometry import rotate_points, viewing_direction
from posevote.model.kernels import (
    kappa_for_width,
    orientation_kernel,
    position_kernel,
    viewpoint_kernel,
)

#: Half width at half maximum of K1, in training-view spacings, for morphed
#: models without a bandwidth of their own (0.5 otherwise): morphed features
#: move with the object, so a wider kernel blends neighbours without blurring
#: them. Chosen on the rendered turntables at the COIL protocol's offsets
#: (``benchmarks/tune_rendered.py``; docs/DEFAULTS.md).
MORPH_BANDWIDTH = 0.75


@dataclass(frozen=True, kw_only=True, eq=False)
class PoseModel:
    """Training pairs defining psi(w, x) (Eq. 1).

    Attributes
    ----------
    xy : ndarray, shape (M, 2)
        Object-centred, scale-normalised feature positions (reference pixels).
    theta : ndarray, shape (M,)
        Feature orientations in ``[0, pi)`` (upright: view in-plane undone).
    view : ndarray of int, shape (M,)
        Training view each feature comes from.
    weight : ndarray, shape (M,)
        Weights ``wt_i`` in ``[0, 1]`` (all ones when weights are off).
    view_azimuth, view_elevation : ndarray, shape (K,)
        Viewpoint ``w1`` of each training view, radians.
    view_box : ndarray, shape (K, 2)
        Box width and height of each view, reference pixels.
    view_instance : ndarray of int, shape (K,)
        Instance index of each view.
    instance_names : tuple of str
        Instance names.
    reference_size : float
        Pixels per reference unit in the training images (median box height).
    category : str
        Category name, "" if none.
    instance_size : tuple of float
        Each instance's median training box height over ``reference_size``:
        the scale at which the model matches the instance at its training
        size (empty: all 1).
    shift : ndarray, shape (M, C, 2), or None
        Each feature's displacement toward each neighbour of its view
        (:mod:`posevote.model.morph`); None: not measured.
    view_neighbour : ndarray of int, shape (K, C), or None
        Each view's next and previous view in azimuth (C = 2), and over the
        sphere in elevation too (C = 4) (-1: none); present with ``shift``.
    view_origin : ndarray, shape (K, 2) or (K, 3), or None
        Where the object's origin (the point ``t_cam_obj`` names, e.g. a
        mesh origin) lies in each view, from its reference point, reference
        pixels, upright, and optionally its depth over the depth the model
        gives that view (:meth:`posevote.estimator.PoseEstimator.fit`'s
        ``origins``); None: not given (``t_cam_obj`` names the box centre).
    view_template : ndarray of float16, shape (K, T, T), or None
        Each view's grey template, upright, NaN outside the object
        (:mod:`posevote.templates.model`); None: not learnt.
    view_template_cell : ndarray, shape (K,), or None
        Reference pixels per template pixel of each view; present with
        ``view_template``.
    view_outline : ndarray, shape (K, A), or None
        Each view's outline: the extent of its mask's convex hull from the
        reference point in ``A`` directions, reference pixels, upright
        (:mod:`posevote.model.outline`; a view without a mask: its box);
        None: trained without masks (a pose's box is its view's box turned).
    view_lookalike : ndarray, shape (K,), or None
        How alike each view is to another side of its instance, in [0, 1]
        (:mod:`posevote.refinement.lookalike`); None: not measured (a model file
        of an earlier posevote).
    keypoint_xy : ndarray, shape (N, 2), or None
        The views' SIFT keypoints (:mod:`posevote.keypoints.model`), from
        their view's reference point, upright, reference pixels; None: not
        learnt.
    keypoint_descriptor : ndarray of uint8, shape (N, 128), or None
        Their descriptors; present with ``keypoint_xy``.
    keypoint_view : ndarray of int, shape (N,), or None
        The view of each keypoint; present with ``keypoint_xy``.
    """

    xy: NDArray[np.float64]
    theta: NDArray[np.float64]
    view: NDArray[np.int64]
    weight: NDArray[np.float64]
    view_azimuth: NDArray[np.float64]
    view_elevation: NDArray[np.float64]
    view_box: NDArray[np.float64]
    view_instance: NDArray[np.int64]
    instance_names: tuple[str, ...]
    reference_size: float
    category: str = ""
    instance_size: tuple[float, ...] = ()
    shift: NDArray[np.float64] | None = None
    view_neighbour: NDArray[np.int64] | None = None
    view_origin: NDArray[np.float64] | None = None
    view_template: NDArray[np.float16] | None = None
    view_template_cell: NDArray[np.float64] | None = None
    view_outline: NDArray[np.float64] | None = None
    view_lookalike: NDArray[np.float64] | None = None
    keypoint_xy: NDArray[np.float64] | None = None
    keypoint_descriptor: NDArray[np.uint8] | None = None
    keypoint_view: NDArray[np.int64] | None = None

    def size_of(self, instance: int) -> float:
        """The training size of an instance relative to the reference (1.0 if unknown)."""
        return float(self.instance_size[instance]) if self.instance_size else 1.0

    @property
    def n_features(self) -> int:
        """Number of training pairs M."""
        return int(self.theta.shape[0])

    @property
    def n_views(self) -> int:
        """Number of training views K."""
        return int(self.view_azimuth.shape[0])

    def view_directions(self) -> NDArray[np.float64]:
        """Viewing direction of each training view, shape (K, 3)."""
        return self._view_directions

    @cached_property
    def _view_directions(self) -> NDArray[np.float64]:
        return viewing_direction(self.view_azimuth, self.view_elevation)

    @cached_property
    def rms_radius(self) -> float:
        """Root-mean-square distance of the features from the reference point (reference units).

        Cached: a pooled category model has hundreds of thousands of features,
        and every search of an image reads it.
        """
        return float(np.sqrt(np.mean(np.sum(self.xy**2, axis=1)))) if len(self.xy) else 0.0

    @cached_property
    def viewpoints(self) -> NDArray[np.float64]:
        """The distinct training viewpoints ``(azimuth, elevation)``, radians, rounded to 1e-9
        and sorted, shape (P, 2); cached, as every search starts from them."""
        pairs = np.asarray(np.unique(np.round(np.stack([self.view_azimuth, self.view_elevation],
                                                       1), 9), axis=0), dtype=np.float64)
        pairs.flags.writeable = False
        return pairs

    def features_of(self, views: NDArray[np.intp]) -> NDArray[np.intp]:
        """Indices of the features of ``views`` (sorted ascending), in increasing order."""
        starts = self._view_starts
        if starts is None:
            chosen = np.zeros(self.n_views, dtype=bool)
            chosen[views] = True
            return np.flatnonzero(chosen[self.view])
        # Features stored view by view: the views' ranges, without a pass over all.
        lo, count = starts[views], starts[views + 1] - starts[views]
        offset = np.concatenate([[0], np.cumsum(count)[:-1]])
        return np.arange(int(count.sum())) + np.repeat(lo - offset, count)

    @cached_property
    def _view_starts(self) -> NDArray[np.intp] | None:
        if len(self.view) and np.any(np.diff(self.view) < 0):
            return None
        return np.searchsorted(self.view, np.arange(self.n_views + 1)).astype(np.intp)

    def instance_model(self, instance: int) -> PoseModel:
        """The training pairs of one instance only (views re-indexed; built once, then cached)."""
        if not 0 <= instance < len(self.instance_names):
            raise ValueError(f"instance {instance} has no training views")
        return self._instance_models[instance]

    @cached_property
    def _instance_models(self) -> tuple[PoseModel, ...]:
        return tuple(self.select_instances([i]) for i in range(len(self.instance_names)))

    def select_instances(self, instances: Sequence[int]) -> PoseModel:
        """The training pairs of some instances only (views and instances re-indexed).

        Raises
        ------
        ValueError
            If an instance has no training views.
        """
        chosen = list(instances)
        for i in chosen:
            if not np.any(self.view_instance == i):
                raise ValueError(f"instance {i} has no training views")
        views = np.flatnonzero(np.isin(self.view_instance, chosen))
        local = np.full(self.n_views, -1, dtype=np.int64)
        local[views] = np.arange(len(views))
        keep = local[self.view] >= 0
        renumber = {old: new for new, old in enumerate(chosen)}
        fields = {k: getattr(self, k) for k in self.__dataclass_fields__}
        fields.update(xy=self.xy[keep], theta=self.theta[keep], view=local[self.view[keep]],
                      weight=self.weight[keep], view_azimuth=self.view_azimuth[views],
                      view_elevation=self.view_elevation[views], view_box=self.view_box[views],
                      view_instance=np.array([renumber[int(i)] for i in self.view_instance[views]],
                                             dtype=np.int64),
                      instance_names=tuple(self.instance_names[i] for i in chosen),
                      instance_size=tuple(self.instance_size[i] for i in chosen)
                      if self.instance_size else (),
                      shift=None if self.shift is None else self.shift[keep],
                      view_neighbour=None if self.view_neighbour is None else np.where(
                          self.view_neighbour[views] >= 0,
                          local[np.maximum(self.view_neighbour[views], 0)], -1),
                      view_origin=None if self.view_origin is None else self.view_origin[views],
                      view_template=None if self.view_template is None
                      else self.view_template[views],
                      view_template_cell=None if self.view_template_cell is None
                      else self.view_template_cell[views],
                      view_outline=None if self.view_outline is None
                      else self.view_outline[views],
                      view_lookalike=None if self.view_lookalike is None
                      else self.view_lookalike[views])
        if self.keypoint_view is not None:
            kept = local[self.keypoint_view] >= 0
            fields.update(keypoint_xy=self.keypoint_xy[kept],  # type: ignore[index]
                          keypoint_descriptor=self.keypoint_descriptor[kept],  # type: ignore[index]
                          keypoint_view=local[self.keypoint_view[kept]])
        return PoseModel(**fields)

    def with_weights(self, weight: NDArray[np.float64]) -> PoseModel:
        """A copy with other feature weights."""
        fields = {k: getattr(self, k) for k in self.__dataclass_fields__}
        fields["weight"] = np.asarray(weight, dtype=np.float64)
        return PoseModel(**fields)


def build_model(
    view_features: Sequence[EdgeFeatures],
    *,
    poses: NDArray[np.float64],
    centers: NDArray[np.float64],
    scales: NDArray[np.float64],
    box_sizes: NDArray[np.float64],
    instances: ArrayLike,
    instance_names: Sequence[str],
    reference_size: float,
    category: str = "",
    instance_size: Sequence[float] = (),
) -> PoseModel:
    """Pool the features of the training views into a :class:`PoseModel`.

    Parameters
    ----------
    view_features : sequence of EdgeFeatures
        Features of each training view, in image pixels, already restricted to
        the object.
    poses : ndarray, shape (K, 3)
        Azimuth, elevation, in-plane angle of each view (radians).
    centers : ndarray, shape (K, 2)
        Reference point ``(u, v)`` of each view (the box centre).
    scales : ndarray, shape (K,)
        Pixels per reference unit of each view.
    box_sizes : ndarray, shape (K, 2)
        Box width and height of each view, pixels.
    instances : array_like of int
        Instance index of each view.
    instance_names : sequence of str
        Names of the instances.
    reference_size : float
        Pixels per reference unit that scale 1 stands for.
    category : str, optional
        Category name.
    instance_size : sequence of float, optional
        Training size of each instance relative to ``reference_size``.

    Returns
    -------
    PoseModel
        With unit weights; see :func:`posevote.model.weights.feature_weights`.
    """
    xy, theta, view = [], [], []
    for k, feats in enumerate(view_features):
        upright = normalize_features(feats, center=centers[k], scale=float(scales[k]),
                                     inplane=float(poses[k, 2]))
        xy.append(upright.xy)
        theta.append(upright.theta)
        view.append(np.full(len(feats), k, dtype=np.int64))
    all_theta = np.concatenate(theta) if theta else np.zeros(0)
    return PoseModel(
        xy=np.concatenate(xy) if xy else np.zeros((0, 2)),
        theta=all_theta,
        view=np.concatenate(view) if view else np.zeros(0, dtype=np.int64),
        weight=np.ones_like(all_theta),
        view_azimuth=np.mod(poses[:, 0], 2 * np.pi),
        view_elevation=poses[:, 1].copy(),
        view_box=box_sizes / scales[:, None],
        view_instance=np.asarray(instances, dtype=np.int64),
        instance_names=tuple(instance_names),
        reference_size=float(reference_size),
        category=category,
        instance_size=tuple(float(f) for f in instance_size),
    )


def viewpoint_kappa(model: PoseModel, bandwidth_deg: float | None = None) -> float:
    """Concentration of K1: from ``bandwidth_deg`` (HWHM), else from the views' spacing."""
    if bandwidth_deg is not None:
        return kappa_for_width(np.radians(bandwidth_deg))
    d = np.unique(np.round(model.view_directions(), 9), axis=0)
    if len(d) < 2:
        return kappa_for_width(np.radians(10.0))
    cosines = np.clip(d @ d.T, -1.0, 1.0)
    np.fill_diagonal(cosines, -1.0)
    spacing = float(np.median(np.arccos(cosines.max(axis=1))))
    return kappa_for_width(spacing * (MORPH_BANDWIDTH if model.shift is not None else 0.5))


def viewpoint_weights(model: PoseModel, azimuth: float, elevation: float, *, kappa: float
                      ) -> NDArray[np.float64]:
    """Pose kernel K1 between a viewpoint and each training view, shape (K,)."""
    probe = viewing_direction(azimuth, elevation)
    return viewpoint_kernel(model.view_directions(), probe, kappa)


def origin_offset(model: PoseModel, azimuth: float, elevation: float, *, kappa: float,
                  k1_cutoff: float) -> NDArray[np.float64] | None:
    """Where the object's origin lies from the reference point at a viewpoint, shape (3,):
    the offset in reference pixels, upright, and the depth factor (1 where the model has
    none): the views' ``view_origin`` averaged with the pose kernel K1 over the views
    where it reaches ``k1_cutoff`` (the nearest view alone if none), as the box is; None
    for a model without them."""
    if model.view_origin is None:
        return None
    origin = model.view_origin if model.view_origin.shape[1] == 3 else np.column_stack(
        [model.view_origin, np.ones(model.n_views)])
    return view_average(model, origin, azimuth, elevation, kappa=kappa, k1_cutoff=k1_cutoff)


def near_views(model: PoseModel, azimuth: float, elevation: float, *, kappa: float,
               k1_cutoff: float) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """The training views whose pose kernel K1 at a viewpoint reaches ``k1_cutoff`` (the
    nearest alone if none does), and K1 at every view, shape (K,)."""
    k1 = viewpoint_weights(model, azimuth, elevation, kappa=kappa)
    views = np.flatnonzero(k1 >= k1_cutoff)
    if len(views) == 0 or not k1[views].sum() > 0:
        views = np.array([int(np.argmax(k1))])
    return views, k1


def view_average(model: PoseModel, values: NDArray[np.float64], azimuth: float,
                 elevation: float, *, kappa: float, k1_cutoff: float) -> NDArray[np.float64]:
    """A per-view quantity (one row per training view) at a viewpoint: averaged with K1
    over :func:`near_views`, the nearest view's own row where it is alone."""
    views, k1 = near_views(model, azimuth, elevation, kappa=kappa, k1_cutoff=k1_cutoff)
    if len(views) == 1:
        return np.array(values[views[0]], dtype=np.float64)
    return np.asarray(np.average(values[views], axis=0, weights=k1[views]), dtype=np.float64)


def image_density(features: EdgeFeatures, x_xy: NDArray[np.float64], x_theta: NDArray[np.float64],
                 *, position_sigma: float, orientation_kappa: float) -> NDArray[np.float64]:
    """phi(x) of Eq. 2 (max-normalised kernels, no 1/N): reference implementation.

    Parameters
    ----------
    features : EdgeFeatures
        Test features x_j.
    x_xy : ndarray, shape (P, 2)
        Positions at which to evaluate.
    x_theta : ndarray, shape (P,)
        Orientations at which to evaluate.
    position_sigma, orientation_kappa : float
        Combined kernel widths (module :mod:`posevote.model.kernels`).

    Returns
    -------
    ndarray, shape (P,)
    """
    d2 = np.sum((x_xy[:, None, :] - features.xy[None, :, :]) ** 2, axis=-1)
    k = position_kernel(d2, position_sigma) * orientation_kernel(
        x_theta[:, None] - features.theta[None, :], orientation_kappa)
    return k.sum(axis=1)


def pose_likelihood(model: PoseModel, features: EdgeFeatures, *, azimuth: float, elevation: float,
                    inplane: float, scale: float, position: tuple[float, float],
                    position_sigma: float, orientation_kappa: float, viewpoint_kappa: float,
                    use_weights: bool = True) -> float:
    """p(w) of Eq. 3 in closed form, exact (no voting): reference and probe.

    ``p(w) = sum_i wt_i K1(w, w_i) phi(T_w x_i) / sum_i wt_i K1(w, w_i)``:
    the training features are moved by the pose's in-plane rotation, scale
    and translation, and each is scored by the test density at its place.
    Scale here is in image pixels per reference unit.

    Returns
    -------
    float
        Weighted fraction of model features explained by the image (0 if the
        viewpoint is far from every training view).
    """
    k1 = viewpoint_weights(model, azimuth, elevation, kappa=viewpoint_kappa)[model.view]
    w = k1 * (model.weight if use_weights else 1.0)
    total = w.sum()
    if total <= 0:
        return 0.0
    xy = scale * rotate_points(model.xy, inplane) + np.asarray(position, dtype=np.float64)
    theta = np.mod(model.theta + inplane, np.pi)
    phi = image_density(features, xy, theta, position_sigma=position_sigma,
                       orientation_kappa=orientation_kappa)
    return float(np.sum(w * phi) / total)
