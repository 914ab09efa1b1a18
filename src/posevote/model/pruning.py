"""Pruning a pooled category model by clustering (Sec. III-A).

The features of all instances, already normalised for translation, in-plane
rotation and scale (object-centred, upright, scale-normalised), are
clustered agglomeratively in the joint pose x appearance space; only the
cluster centres are kept, each carrying its members' total weight. So that
model size grows sub-linearly with the number of instances (Fig. 4).

The two knobs bound the within-cluster variance in pose and in appearance.
Coordinates are scaled so that one unit is the allowed standard deviation:

- pose: the viewing direction of the feature's view (a unit vector)
  divided by ``pose_std`` (radians; chord ~ angle for small angles);
- appearance: the position divided by ``position_sigma`` and the doubled
  orientation as a point ``sqrt(orientation_kappa) * (cos 2θ, sin 2θ)`` (one
  unit is one standard deviation of the von Mises kernel), all divided by
  ``appearance_std``.

Clusters are formed by complete linkage on ``max(d_pose, d_appearance)``
cut at ``sqrt(2)``: every pair of members is then within ``sqrt(2)`` in
both spaces, which bounds the within-cluster variance (the mean squared
distance to the centroid, half the mean squared pairwise distance) by 1 in
each: the knobs are exactly the maximum within-cluster standard deviations.

Complete linkage is quadratic in memory, so the feature set is first cut
into blocks of at most ``max_block`` features by recursive median splits
along the widest coordinate (a k-d tree); clusters do not cross block
boundaries, which costs a little pruning and nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from posevote.model.density import PoseModel


@dataclass(frozen=True, kw_only=True)
class PruningPreset:
    """The two knobs of the clustering.

    Attributes
    ----------
    pose_std_deg : float
        Maximum within-cluster standard deviation of the viewing direction,
        degrees.
    appearance_std : float
        Maximum within-cluster standard deviation in appearance, in widths
        of the appearance kernel K2 (position sigma; orientation von Mises
        standard deviation).
    """

    pose_std_deg: float
    appearance_std: float


#: Named presets, chosen on the features of EPFL cars (model size only, no test
#: image involved) for the share of a car model's features each keeps
#: (benchmarks/pruning.py; docs/DEFAULTS.md, ``prune``).
PRESETS: dict[str, PruningPreset] = {
    "moderate": PruningPreset(pose_std_deg=10.0, appearance_std=1.2),
    "aggressive": PruningPreset(pose_std_deg=20.0, appearance_std=2.0),
}


def resolve_preset(prune: str | PruningPreset | None) -> PruningPreset | None:
    """A preset from its name (``"moderate"``, ``"aggressive"``), or as given.

    Raises
    ------
    ValueError
        On an unknown name or non-positive knobs.
    """
    if prune is None or prune == "none":
        return None
    if isinstance(prune, str):
        if prune not in PRESETS:
            raise ValueError(f"unknown pruning preset {prune!r}; choose one of "
                             f"{', '.join(['none', *PRESETS])}")
        return PRESETS[prune]
    if not (prune.pose_std_deg > 0 and prune.appearance_std > 0):
        raise ValueError(f"pruning knobs must be positive, got {prune}")
    return prune


def _blocks(coords: NDArray[np.float64], max_block: int) -> list[NDArray[np.intp]]:
    """Index blocks of at most ``max_block`` rows, by recursive median splits."""
    out: list[NDArray[np.intp]] = []
    stack = [np.arange(len(coords))]
    while stack:
        idx = stack.pop()
        if len(idx) <= max_block:
            out.append(idx)
            continue
        sub = coords[idx]
        axis = int(np.argmax(np.ptp(sub, axis=0)))
        order = np.argsort(sub[:, axis], kind="stable")
        half = len(idx) // 2
        stack.append(idx[order[:half]])
        stack.append(idx[order[half:]])
    return out


def cluster_features(pose: NDArray[np.float64], appearance: NDArray[np.float64], *,
                     max_block: int = 2048) -> NDArray[np.int64]:
    """Cluster labels under the bound ``max(d_pose, d_appearance) <= sqrt(2)``.

    Parameters
    ----------
    pose, appearance : ndarray, shape (M, P) and (M, A)
        Coordinates already scaled so that one unit is the allowed standard
        deviation.
    max_block : int, optional
        Largest block clustered at once (memory grows as its square).

    Returns
    -------
    ndarray of int, shape (M,)
        Cluster label of every feature, ``0 .. n_clusters - 1``.
    """
    # imported where used, so that a command-line start does not pay for it
    from scipy.cluster.hierarchy import fcluster, linkage
    from scipy.spatial.distance import pdist

    m = len(pose)
    labels = np.zeros(m, dtype=np.int64)
    next_label = 0
    for idx in _blocks(np.hstack([pose, appearance]), max_block):
        if len(idx) == 1:
            labels[idx] = next_label
            next_label += 1
            continue
        dist = np.maximum(pdist(pose[idx]), pdist(appearance[idx]))
        tree = linkage(dist, method="complete")
        local = fcluster(tree, t=np.sqrt(2.0), criterion="distance") - 1
        labels[idx] = local + next_label
        next_label += int(local.max()) + 1
    return labels


def prune_model(model: PoseModel, preset: PruningPreset, *, position_sigma: float,
                orientation_kappa: float, max_block: int = 2048) -> PoseModel:
    """Keep only the cluster centres of a (pooled) model.

    Parameters
    ----------
    model : PoseModel
        The full model, with its feature weights.
    preset : PruningPreset
        The knobs.
    position_sigma : float
        Appearance kernel width in position, reference pixels.
    orientation_kappa : float
        Appearance kernel concentration in doubled orientation.
    max_block : int, optional
        See :func:`cluster_features`.

    Returns
    -------
    PoseModel
        One feature per cluster: weighted mean position, circular mean
        orientation, the view of the member nearest the mean viewing
        direction, and the members' total weight.
    """
    if model.n_features == 0:
        return model
    directions = model.view_directions()[model.view]
    pose = directions / np.radians(preset.pose_std_deg)
    root_kappa = np.sqrt(orientation_kappa)
    appearance = np.column_stack([
        model.xy / position_sigma,
        root_kappa * np.cos(2.0 * model.theta),
        root_kappa * np.sin(2.0 * model.theta),
    ]) / preset.appearance_std
    labels = cluster_features(pose, appearance, max_block=max_block)
    n = int(labels.max()) + 1
    # Weighted means (members with zero weight still count a little, so that
    # an all-zero cluster keeps a defined centre).
    w = model.weight + 1e-12
    total = np.bincount(labels, weights=w, minlength=n)

    def mean(values: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.bincount(labels, weights=w * values, minlength=n) / total

    xy = np.column_stack([mean(model.xy[:, 0]), mean(model.xy[:, 1])])
    theta = np.mod(0.5 * np.arctan2(mean(np.sin(2 * model.theta)),
                                    mean(np.cos(2 * model.theta))), np.pi)
    centre_dir = np.column_stack([mean(directions[:, c]) for c in range(3)])
    # The view of each cluster: its member whose viewing direction is nearest
    # the cluster's mean direction.
    closeness = np.sum(directions * centre_dir[labels], axis=1)
    order = np.lexsort((-closeness, labels))
    first = order[np.r_[True, labels[order][1:] != labels[order][:-1]]]
    view = np.empty(n, dtype=np.int64)
    view[labels[first]] = model.view[first]
    weight = np.bincount(labels, weights=model.weight, minlength=n)
    fields = {k: getattr(model, k) for k in model.__dataclass_fields__}
    fields.update(xy=xy, theta=theta, view=view, weight=weight)
    if model.shift is not None:
        # A centre moves as its members do (they come from nearby views).
        fields["shift"] = np.stack([np.column_stack([mean(model.shift[:, c, d]) for d in (0, 1)])
                                    for c in range(model.shift.shape[1])], axis=1)
    return PoseModel(**fields)
