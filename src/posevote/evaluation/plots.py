"""Pictures: feature weights (the paper's Fig. 3) and estimate overlays (Fig. 9)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from posevote._io import atomic_write_with
from posevote.data.images import as_gray_float
from posevote.model.density import PoseModel
from posevote.results import Hypothesis, PoseEstimate


def plot_weights(model: PoseModel, path: str | Path, *, n_views: int = 6) -> None:
    """Draw the training features of a few views coloured by weight (Fig. 3).

    Darker means heavier: features that also appear in views of very
    different pose (Eq. 4) are pale.

    Parameters
    ----------
    model : PoseModel
        A trained model.
    path : str or Path
        PNG file to write (atomically).
    n_views : int, optional
        Number of training views shown, evenly spread over the model's views.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if model.n_views == 0:
        raise ValueError("the model has no training views")
    order = np.argsort(model.view_azimuth, kind="stable")
    shown = order[np.linspace(0, len(order) - 1, min(n_views, len(order))).round().astype(int)]
    fig, axes = plt.subplots(1, len(shown), figsize=(2.6 * len(shown), 3.0), squeeze=False)
    half = 0.5 * np.abs(model.xy).max() * 2.0 + 1.0
    scatter = None
    for ax, k in zip(axes[0], shown, strict=True):
        sel = model.view == k
        xy, theta, wt = model.xy[sel], model.theta[sel], model.weight[sel]
        # Short segments along each edge tangent, coloured by weight.
        seg = 1.5 * np.stack([np.cos(theta), np.sin(theta)], axis=1)
        for (x, y), (dx, dy), w in zip(xy, seg, wt, strict=True):
            ax.plot([x - dx, x + dx], [y - dy, y + dy], color=plt.cm.Greys(0.15 + 0.85 * w), lw=1.6)
        scatter = ax.scatter(xy[:, 0], xy[:, 1], c=wt, cmap="Greys", vmin=0, vmax=1, s=0)
        ax.set_xlim(-half, half)
        ax.set_ylim(half, -half)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        name = model.instance_names[model.view_instance[k]] if model.instance_names else ""
        ax.set_title(f"{name} azimuth {np.degrees(model.view_azimuth[k]):.0f}°", fontsize=9)
    if scatter is not None:
        fig.colorbar(scatter, ax=axes[0].tolist(), shrink=0.8, label="weight wt (Eq. 4)")
    fig.suptitle("Training features coloured by pose specificity (darker = heavier)", fontsize=10)
    atomic_write_with(path, lambda tmp: fig.savefig(tmp, dpi=110))
    plt.close(fig)


def _rose(canvas: NDArray[np.uint8], hyps: Sequence[Hypothesis], *, centre: tuple[int, int],
          radius: int) -> None:
    """Orientation rose: the object's front seen from above (Fig. 9)."""
    cv2.circle(canvas, centre, radius, (255, 255, 255), -1, cv2.LINE_AA)
    cv2.circle(canvas, centre, radius, (60, 60, 60), 1, cv2.LINE_AA)
    colours = [(0, 0, 230), (0, 160, 255), (0, 200, 255)]
    for rank, hyp in reversed(list(enumerate(hyps[:3]))):
        # Azimuth 0 shows the front to the camera: the arrow points down
        # (towards the viewer, seen from above); azimuth turns it.
        ang = hyp.azimuth
        tip = (int(round(centre[0] + radius * 0.85 * np.sin(ang))),
               int(round(centre[1] + radius * 0.85 * np.cos(ang))))
        cv2.arrowedLine(canvas, centre, tip, colours[rank], 2 if rank == 0 else 1, cv2.LINE_AA,
                        tipLength=0.3)


def draw_overlay(image: NDArray, estimate: PoseEstimate, *, truth_box: Sequence[float] | None = None,
                 label: str | None = None) -> NDArray[np.uint8]:
    """The image with the estimated box and an orientation rose (Fig. 9).

    Parameters
    ----------
    image : ndarray
        The test image.
    estimate : PoseEstimate
        The estimate to draw.
    truth_box : sequence of float, optional
        True box ``(x, y, w, h)``, drawn in green.
    label : str, optional
        Text written at the bottom (defaults to the best mode's azimuth, score and
        probability). A legend beside the rose says what the arrows, colours and
        0 degrees are.

    Returns
    -------
    ndarray, shape (H', W', 3), uint8
        BGR image, upscaled so that small images stay legible.
    """
    gray = as_gray_float(image)
    zoom = max(1, int(np.ceil(256 / max(gray.shape))))
    canvas = np.asarray(cv2.cvtColor((gray * 255).astype(np.uint8), cv2.COLOR_GRAY2BGR),
                        dtype=np.uint8)
    canvas = np.asarray(cv2.resize(canvas, None, fx=zoom, fy=zoom,
                                   interpolation=cv2.INTER_NEAREST), dtype=np.uint8)
    if truth_box is not None:
        x, y, w, h = (float(t) * zoom for t in truth_box)
        cv2.rectangle(canvas, (int(x), int(y)), (int(x + w), int(y + h)), (0, 200, 0), 1)
    radius = max(14, min(canvas.shape[:2]) // 10)
    if estimate.best is not None:
        x, y, w, h = (float(t) * zoom for t in estimate.best.box)
        cv2.rectangle(canvas, (int(x), int(y)), (int(x + w), int(y + h)), (0, 0, 230), 2)
        u, v = (float(t) * zoom for t in estimate.best.position)
        cv2.drawMarker(canvas, (int(u), int(v)), (0, 0, 230), cv2.MARKER_CROSS, 10, 1)
        _rose(canvas, estimate.modes, centre=(radius + 4, radius + 4), radius=radius)
        legend = ["arrow: the object's front, seen from above",
                  "pointing down: azimuth 0, front to the camera",
                  "red: best mode (box, arrow); orange, yellow: next modes"]
        if truth_box is not None:
            legend.append("green: the true box")
        for row, line in enumerate(legend):
            _text(canvas, line, (2 * radius + 12, 12 + 13 * row), 0.36)
        best = estimate.best
        text = label or (f"azimuth {best.azimuth_deg:.1f} deg  score {best.score:.2f}  "
                         f"p {best.probability:.2f}")
    else:
        text = label or "not found"
    _text(canvas, text, (4, canvas.shape[0] - 6), 0.45)
    return canvas


def _text(canvas: NDArray[np.uint8], text: str, at: tuple[int, int], size: float) -> None:
    """White text outlined in black: legible on any image."""
    cv2.putText(canvas, text, at, cv2.FONT_HERSHEY_SIMPLEX, size, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(canvas, text, at, cv2.FONT_HERSHEY_SIMPLEX, size, (255, 255, 255), 1,
                cv2.LINE_AA)


def write_png(path: str | Path, image_bgr: NDArray[np.uint8]) -> None:
    """Write a BGR image as PNG, atomically."""
    def writer(tmp: Path) -> None:
        if not cv2.imwrite(str(tmp), image_bgr):
            raise OSError(f"could not write {path}")

    atomic_write_with(path, writer)
