"""Stage 5: estimates become scores, tables and plots."""

from posevote.evaluation.metrics import box_iou, summarize_errors
from posevote.evaluation.synthetic import PastedView, clutter_background, paste_on_clutter

__all__ = ["PastedView", "box_iou", "clutter_background", "paste_on_clutter", "summarize_errors"]
