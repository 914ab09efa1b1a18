"""Stage 4: probes become continuous pose hypotheses (Sec. II-B)."""

from posevote.refinement.fitting import box_from_pose, find_modes, refine_mode
from posevote.refinement.local import polish_pose

__all__ = ["box_from_pose", "find_modes", "polish_pose", "refine_mode"]
