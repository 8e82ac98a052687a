"""What the motion planner's work costs on the effort clock (:mod:`models.clock`).

Every module of planner/ reports its work through ``clock.work(kind, units)``; this module
prices every such kind, in reference seconds as ``(per call, per unit)``, and registers the
table with :func:`models.clock.register_work_costs` when it is imported (``planner``'s
``__init__`` imports it, so the table is registered before any planner module runs).

The costs are a non-negative least-squares fit of the CPU seconds of real legs on the
counts of each kind (``python benchmarks/effort_motion.py`` prints one as ``fitted_work_s``),
scaled so that an effort second is a CPU second of the reference machine (2 cores, AMD EPYC):
every cost of the fit by 0.400, the earliest departure's by 0.178 (scaled as the others, the
regression legs of ``tests/data/motion_legs.json``, where the departure search is most of the
work, cost 1.7 effort seconds per CPU second). Measured with these costs (2 cores, nothing
else running):

* ``python benchmarks/effort_motion.py --fields 2 --seed 5``: effort / CPU seconds per leg
  of median 0.96, all 60 legs within 0.59-1.16;
* ``tests/test_effort_calibration.py`` (the five regression legs, 3 s budget): 0.86-0.91
  over the legs together (three runs). It fails outside 0.5-2.0: then re-fit with the command
  above.
"""

from __future__ import annotations

from models import clock

__all__ = ["PLANNER_WORK_S"]

#: Reference seconds of each kind of planner work, as (per call, per unit).
PLANNER_WORK_S: dict[str, tuple[float, float]] = {
    "departure": (0.0, 1.96e-07),  # planner.timeline: one earliest departure; unit: move samples
    "free_after": (0.0, 0.0),  # planner.timeline: a rest check; unit: poses
    "move_samples": (0.0, 0.0),  # planner.timeline: a straight move sampled; unit: samples
    "clearance_rows": (0.0, 1.56e-08),  # planner.clearance: unit: rows of body pairs
    "clearance_to_arms": (3.88e-05, 0.0),  # planner.clearance: unit: arm x sample clearances
    "walk": (0.0, 4.4e-07),  # planner.clearance: delay-table walks; unit: exact clearances
    "segments": (3.04e-05, 2.32e-07),  # planner.geometry: forward kinematics; unit: poses
    "zoa_edges": (0.0, 7.57e-07),  # planner.geometry: ZoA test of straight edges; unit: edges
    "csp_nodes": (1.28e-05, 0.0),  # planner.delays: unit: search nodes
    "verify": (0.0, 2.72e-06),  # planner.verify: unit: pair samples computed
    # planner.sky: the spare arms of a pointing's configurations placed on sky; unit: idle
    # arms (a least-squares fit of place_sky's CPU seconds on the 11 pointings of a 300-star
    # cluster programme, 1-21 configurations, 2-17 idle arms: its candidate rests per call,
    # the collision checks per arm)
    "sky_arms": (0.019, 3.0e-04),
}

clock.register_work_costs(PLANNER_WORK_S)
