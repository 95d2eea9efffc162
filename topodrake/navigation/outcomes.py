"""The outcome of one drive as every driving command reports it.

``navigate``, ``demo`` and ``drive`` name an outcome with one vocabulary,
judged by the studies' success rule
(:func:`~topodrake.experiments.plan_trials.judge_outcome`), and exit with
status 0 only when the car reached its goal:

- ``reached``: within the success radius of the goal (exit 0);
- ``false_reached``: the follower ended its plan farther from the goal;
- ``collision``, ``timeout``, ``search_failed``, ``dead_reckoning_gave_up``:
  the drive stopped there (all exit :data:`EXIT_FAILED`).
"""

from __future__ import annotations

import numpy as np


#: the relaxed goal radius of the paper's planning protocol (m)
SUCCESS_M = 0.54

OUTCOMES = ("reached", "false_reached", "collision", "timeout", "search_failed",
            "dead_reckoning_gave_up")
#: the exit status of a drive that did not reach its goal
EXIT_FAILED = 3
#: the expert runner's names in this vocabulary
_EXPERT = {"success": "reached"}


def goal_distance(poses, goal) -> float:
    """Metres from a drive's last pose to the goal position."""
    return float(np.hypot(*(np.asarray(poses)[-1, :2] - np.asarray(goal)[:2])))


def drive_outcome(outcome: str, distance_to_goal_m: float) -> str:
    """A runner's outcome in :data:`OUTCOMES`, judged at ``distance_to_goal_m``."""
    return judge_outcome(_EXPERT.get(outcome, outcome), distance_to_goal_m)


def exit_status(outcome: str) -> int:
    """0 for ``reached``, :data:`EXIT_FAILED` for every other outcome."""
    return 0 if outcome == "reached" else EXIT_FAILED


__all__ = ["OUTCOMES", "EXIT_FAILED", "SUCCESS_M", "drive_outcome", "exit_status",
           "goal_distance"]


def judge_outcome(outcome: str, distance_to_goal_m: float, radius: float = SUCCESS_M) -> str:
    """A follower's outcome under the success rule: ``reached`` farther than
    ``radius`` from the goal is ``false_reached`` (the follower ended its
    plan away from the goal)."""
    return "false_reached" if outcome == "reached" and distance_to_goal_m > radius else outcome
