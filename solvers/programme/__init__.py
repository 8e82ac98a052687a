"""The programme level, between segmentation and allocation: the pointings, position angles
and members of a whole programme with the fewest exposures, and a proven lower bound on its
exposures (docs/programme.md).

Modules, one noun each: :mod:`.candidates` (the maximal sets one FOV holds), :mod:`.model`
(the HiGHS model choosing pointings), :mod:`.reach` (arm reach rows), :mod:`.bound` (the
proven bound), :mod:`.fill` (the allocation feedback and position angles),
:mod:`.optimiser` (the driver) and :mod:`.segment` (one entry point for every mode)."""

from solvers.programme.bound import ExposureBound, lower_bound
from solvers.programme.fill import FillOptions
from solvers.programme.optimiser import OptimiserOptions, ProgrammeResult, optimise
from solvers.programme.segment import MODES, segment_programme

__all__ = ["MODES", "ExposureBound", "FillOptions", "OptimiserOptions", "ProgrammeResult", "lower_bound",
           "optimise", "segment_programme"]
