"""Field segmentation into telescope pointings (thesis ch. 4): :func:`segment_field`
(:mod:`.field`), threshold complete linkage (:mod:`.linkage`, Algorithm 1) and the
smallest enclosing circle (:mod:`.enclosing_circle`, Algorithm 2)."""

from solvers.segmentation.enclosing_circle import smallest_enclosing_circle
from solvers.segmentation.field import (
    FOV_TOL_MM,
    Pointing,
    Segmentation,
    field_plane,
    segment_field,
)
from solvers.segmentation.linkage import (
    SCIPY_MAX_POINTS,
    nn_chain_complete_linkage,
    sparse_complete_linkage,
    threshold_complete_linkage,
)

__all__ = ["FOV_TOL_MM", "SCIPY_MAX_POINTS", "Pointing", "Segmentation", "field_plane", "nn_chain_complete_linkage",
           "segment_field", "smallest_enclosing_circle", "sparse_complete_linkage", "threshold_complete_linkage"]
