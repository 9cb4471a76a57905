"""Make a crash out of a real drive: move one real agent so that it meets the ego.

KITTI drives have no collisions. To test the search on real trajectories, one agent's whole
trajectory is translated (a rigid shift, its motion unchanged) so that at ``time_s`` its centre
sits at ``(lon, lat)`` metres in the ego's frame at that instant (default: centres coincide,
i.e. the boxes overlap). The shift, the agent and the time are recorded in ``provenance.history``
and ``warnings`` and the scenario's ``collision`` is set, so nobody mistakes it for a real crash.
"""

from __future__ import annotations

import numpy as np

from deepcrashtest.errors import UserError
from deepcrashtest.scenario import Collision, Scenario, Trajectory


def pick_agent(scenario: Scenario, min_duration_s: float = 1.0) -> tuple[int, float]:
    """A default agent and time: the longest-observed agent, at the middle of its overlap with the ego.

    Returns ``(agent_id, time_s)``.
    """
    ego_t = scenario.ego.trajectory.t
    best: tuple[float, int, float] | None = None
    for a in scenario.agents:
        t0 = max(a.trajectory.t[0], ego_t[0])
        t1 = min(a.trajectory.t[-1], ego_t[-1])
        if t1 - t0 >= min_duration_s and (best is None or t1 - t0 > best[0]):
            best = (t1 - t0, a.id, 0.5 * (t0 + t1))
    if best is None:
        raise UserError(f"{scenario.name}: no agent is observed for >= {min_duration_s} s alongside the ego")
    return best[1], round(best[2], 2)


def inject_crash(
    scenario: Scenario, agent_id: int | None = None, time_s: float | None = None, lon: float = 0.0, lat: float = 0.0
) -> Scenario:
    """A copy of ``scenario`` in which agent ``agent_id`` is shifted to meet the ego at ``time_s``.

    ``lon, lat``: where the agent's centre lands at ``time_s``, metres, in the ego frame (forward,
    left) at that instant. Defaults pick the agent with the longest overlap (``pick_agent``).
    """
    if agent_id is None or time_s is None:
        a_id, t_c = pick_agent(scenario)
        agent_id = a_id if agent_id is None else agent_id
        time_s = t_c if time_s is None else time_s
    try:
        agent = scenario.vehicle(agent_id)
    except KeyError:
        raise UserError(f"{scenario.name}: no agent with id {agent_id}") from None
    if agent_id == scenario.ego.id:
        raise UserError("the crash partner must be an agent, not the ego")
    tr = agent.trajectory
    if not (tr.t[0] <= time_s <= tr.t[-1]):
        raise UserError(f"agent {agent_id} is observed {tr.t[0]:.2f}-{tr.t[-1]:.2f} s, not at {time_s} s")
    ego = scenario.ego.trajectory.state_at(time_s)
    other = tr.state_at(time_s)
    c, s = np.cos(ego["yaw"]), np.sin(ego["yaw"])
    target = np.array([ego["x"] + c * lon - s * lat, ego["y"] + s * lon + c * lat])
    shift = target - np.array([other["x"], other["y"]])
    a = tr.arrays()
    moved = Trajectory.from_arrays(a["t"], a["x"] + shift[0], a["y"] + shift[1], a["yaw"], a["speed"], tr.observed)
    agents = [
        v.model_copy(update={"trajectory": moved, "spline": _shift_spline(v.spline, shift)}) if v.id == agent_id else v
        for v in scenario.agents
    ]
    note = (
        f"crash injected: agent {agent_id} translated by ({shift[0]:.2f}, {shift[1]:.2f}) m so that its centre is at "
        f"({lon:g}, {lat:g}) m in the ego frame at t={time_s:g} s (deepcrashtest.search.crash.inject_crash)"
    )
    prov = scenario.provenance.model_copy(update={"history": [*scenario.provenance.history, note]})
    return scenario.model_copy(
        update={
            "agents": agents,
            "collision": Collision(time_s=float(time_s), agent_id=agent_id, other_id=scenario.ego.id),
            "provenance": prov,
            "warnings": [*scenario.warnings, "synthetic crash: " + note],
        }
    )


def _shift_spline(spline, shift: np.ndarray):  # type: ignore[no-untyped-def]
    if spline is None:
        return None
    return spline.model_copy(
        update={"cx": [v + float(shift[0]) for v in spline.cx], "cy": [v + float(shift[1]) for v in spline.cy]}
    )
