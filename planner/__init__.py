"""Motion planning for the MXS probe arms (thesis ch. 6): roadmaps, state-time search,
prioritized planning with replanning, an independent verifier and controller commands."""

from planner.commands import MotorSteps, controller_commands, stop_count, to_motor_steps
from planner.prioritized import plan_chain, plan_motion
from planner.verify import VerificationReport, Violation, verify_plan, verify_trajectories

__all__ = [
    "plan_motion",
    "plan_chain",
    "verify_trajectories",
    "verify_plan",
    "VerificationReport",
    "Violation",
    "controller_commands",
    "stop_count",
    "to_motor_steps",
    "MotorSteps",
]
