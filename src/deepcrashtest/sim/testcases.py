"""Crash test cases built from real trajectories: move one real agent so that it meets the ego (or another agent).

KITTI sequences contain no crash. To check that a crash in a scenario happens in the simulation
(at the right time, with the right vehicle), :func:`meet_ego` translates one real agent's whole
trajectory (no rotation, no re-timing: its real speed and heading profile are kept) so that at
``t_contact`` its centre lies ``(ego length + agent length) / 2`` ahead of the ego's centre along
the ego's heading: an oncoming agent then meets the ego front to front at ``t_contact``; a parked
one is hit from behind.
"""

from __future__ import annotations

import numpy as np

from deepcrashtest.errors import UserError
from deepcrashtest.scenario import Collision, Scenario, Trajectory


def meet_ego(scenario: Scenario, agent_id: int, t_contact: float) -> Scenario:
    """A copy of ``scenario`` where agent ``agent_id`` is shifted to touch the ego at ``t_contact`` (s)."""
    return meet(scenario, agent_id, scenario.ego.id, t_contact)


def meet(scenario: Scenario, agent_id: int, target_id: int, t_contact: float) -> Scenario:
    """A copy of ``scenario`` where agent ``agent_id`` is shifted to touch road user ``target_id`` (the ego,
    or another agent: a third-party crash) at ``t_contact`` (s), front to front along the target's heading."""
    try:
        agent = next(a for a in scenario.agents if a.id == agent_id)
        target = scenario.vehicle(target_id)
    except (StopIteration, KeyError):
        raise UserError(f"scenario {scenario.name} has no road users {agent_id} and {target_id}") from None
    tr = agent.trajectory
    for v in (agent, target):
        vt = v.trajectory
        if not vt.t[0] <= t_contact <= vt.t[-1]:
            raise UserError(f"road user {v.id} exists {vt.t[0]:.1f}-{vt.t[-1]:.1f} s, not at t_contact={t_contact} s")
    goal = target.trajectory.state_at(t_contact)
    a = tr.arrays()
    ax, ay = np.interp(t_contact, a["t"], a["x"]), np.interp(t_contact, a["t"], a["y"])
    if agent.trajectory_class is None and np.ptp(a["x"]) + np.ptp(a["y"]) < 3.0:  # parked: use its mean position
        ax, ay = float(np.mean(a["x"])), float(np.mean(a["y"]))
    gap = 0.5 * (target.length + agent.length)
    point = np.array([goal["x"], goal["y"]]) + gap * np.array([np.cos(goal["yaw"]), np.sin(goal["yaw"])])
    shift = point - np.array([ax, ay])
    moved = agent.model_copy(
        update={
            "trajectory": Trajectory.from_arrays(
                a["t"], a["x"] + shift[0], a["y"] + shift[1], a["yaw"], a["speed"], observed=tr.observed
            )
        }
    )
    who = "ego" if target_id == scenario.ego.id else f"agent{target_id}"
    return scenario.evolve(
        name=f"{scenario.name}_agent{agent_id}_meets_{who}_at_{t_contact:g}s",
        agents=[moved if a.id == agent_id else a for a in scenario.agents],
        collision=Collision(time_s=float(t_contact), agent_id=agent_id, other_id=target_id, source="user"),
        provenance=scenario.provenance.model_copy(
            update={
                "history": [
                    *scenario.provenance.history,
                    f"sim.testcases.meet: agent {agent_id} translated by ({shift[0]:.2f}, {shift[1]:.2f}) m "
                    f"to touch road user {target_id} at t={t_contact} s",
                ]
            }
        ),
        warnings=[*scenario.warnings, f"agent {agent_id}'s real trajectory was moved to create a collision (test)"],
    )
