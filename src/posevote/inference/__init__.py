"""Stage 3: a model and a new image become probes of p(w) (Fig. 2)."""

from posevote.inference.maps import TestMaps, prepare_test
from posevote.inference.search import ProbeSet, probe_poses, viewpoint_grid
from posevote.inference.voting import search_translations

__all__ = ["ProbeSet", "TestMaps", "prepare_test", "probe_poses", "search_translations",
           "viewpoint_grid"]
