"""Motion planning for the MXS probe arms (thesis ch. 6): one driver (:mod:`planner.driver`)
trying strategies (:mod:`planner.strategies`) behind one interface (:mod:`planner.strategy`),
the search primitives (roadmaps, state-time search, the delay CSP, Algorithm 6), an
independent verifier and controller commands.

Importing the package registers the planner's work costs (:mod:`planner.effort`) with the
effort clock, before any of its modules reports work."""

from planner import effort  # noqa: F401  (registers PLANNER_WORK_S with models.clock)
from planner.commands import MotorSteps, controller_commands, stop_count, to_motor_steps
from planner.driver import plan_chain, plan_motion
from planner.options import MotionOptions
from planner.verify import VerificationReport, Violation, verify_plan, verify_trajectories

__all__ = [
    "plan_motion",
    "plan_chain",
    "MotionOptions",
    "verify_trajectories",
    "verify_plan",
    "VerificationReport",
    "Violation",
    "controller_commands",
    "stop_count",
    "to_motor_steps",
    "MotorSteps",
]
