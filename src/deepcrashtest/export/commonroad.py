"""CommonRoad scenario XML (commonroad-io 2024.3) from a Scenario.

* Time: CommonRoad counts integer time steps of ``dt`` seconds (default 0.1 s); step k is
  Scenario time ``k * dt``. Every trajectory is resampled (linear interpolation of x, y, yaw,
  speed) at the steps inside its span.
* Lanelet network: one lanelet per lane of ``Scenario.road``, same layout as the OpenDRIVE export
  (:func:`deepcrashtest.geometry.road.boundary_offsets` around the same reference line,
  sampled every ``LANELET_STEP_M`` metres; at most ``MAX_LANELET_VERTICES`` samples on a long road).
  Lanelet id ``1 + lane index`` (0 = rightmost); neighbours are linked as adjacent in the same direction.
  The oncoming lanes (``Road.oncoming_lane_count``) follow with ids ``lane_count + 1 + k`` (k = 0 next to the
  ego's carriageway), their vertices running the opposite way; without a median the innermost one and the
  ego carriageway's lanelet next to it (the leftmost; in left-hand traffic, ``Road.driving_side`` ``left``, the
  rightmost, the oncoming lanes lying right of it) are each other's neighbour in the opposite direction (left in
  right-hand traffic, right in left-hand traffic).
* Agents: dynamic obstacles (id ``OBSTACLE_ID_BASE + vehicle id``), rectangle shape of the
  vehicle's length x width, initial state at the first step of their span, a trajectory
  prediction over the remaining steps. Agents whose span holds fewer than two steps are left out
  (reported).
* Ego: the planning problem (id ``OBSTACLE_ID_BASE + ego id``): initial state at its first step;
  goal region: a ``GOAL_LENGTH_M`` x road-width rectangle centred ``GOAL_AHEAD_M`` metres past the
  crash point (``Scenario.collision`` x/y when the ego is in it, else the ego's position at the
  collision time; without a collision the ego's last position) along the ego's heading there,
  reachable from the step after the crash on.
* Written with commonroad-io's validity check (the CommonRoad XSD) on.

:func:`ego_collision_steps` runs the CommonRoad drivability checker's collision checker for the
ego's recorded path against a (re)loaded CommonRoad scenario: the crash check.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from deepcrashtest.errors import UserError
from deepcrashtest.export.opendrive import reference_line, sample_reference_line
from deepcrashtest.fileio import atomic_path
from deepcrashtest.geometry.road import boundary_offsets, oncoming_boundary_offsets
from deepcrashtest.scenario import Road, Scenario, Vehicle, wrap_angle

COMMONROAD_DT_S = 0.1
LANELET_STEP_M = 1.0
MAX_LANELET_VERTICES = 5_000  # per boundary: a road longer than 5 km is sampled more coarsely (export time)
OBSTACLE_ID_BASE = 1000
GOAL_LENGTH_M = 10.0
GOAL_AHEAD_M = 15.0


def _protobuf_guard() -> None:
    """Let commonroad-io load under a protobuf newer than the 3.20 it was generated for.

    commonroad-io 2024.3 pins protobuf 3.20.2; installing e.g. Ray beside it upgrades protobuf,
    and then importing commonroad fails ("Descriptors cannot be created directly") unless the
    pure-Python protobuf implementation is selected before protobuf is first imported.
    """
    import sys
    from importlib.metadata import PackageNotFoundError, version

    if "google.protobuf" in sys.modules:
        return
    try:
        major = int(version("protobuf").split(".")[0])
    except (PackageNotFoundError, ValueError):
        return
    if major > 3:
        os.environ.setdefault("PROTOCOL_BUFFERS_PYTHON_IMPLEMENTATION", "python")


_protobuf_guard()

_OBSTACLE_TYPE = {
    "car": "CAR",
    "van": "CAR",
    "truck": "TRUCK",
    "bus": "BUS",
    "motorcycle": "MOTORCYCLE",
    "bicycle": "BICYCLE",
    "pedestrian": "PEDESTRIAN",
}


def resample(vehicle: Vehicle, dt: float = COMMONROAD_DT_S) -> dict[str, np.ndarray]:
    """States at the integer steps inside the vehicle's span (from its start delay on).

    Returns arrays ``step`` (int), ``t`` (s), ``x``, ``y`` (m), ``yaw`` (rad, unwrapped), ``speed`` (m/s).
    """
    a = vehicle.trajectory.arrays()
    t0 = max(float(vehicle.start_delay_s), float(a["t"][0]))
    k0 = math.ceil(t0 / dt - 1e-9)
    k1 = math.floor(float(a["t"][-1]) / dt + 1e-9)
    steps = np.arange(k0, k1 + 1)
    t = steps * dt
    out = {k: np.interp(t, a["t"], a[k]) for k in ("x", "y", "yaw", "speed")}
    return {"step": steps, "t": t, **out}


def _lanelet_network(sc: Scenario) -> Any:
    from commonroad.scenario.lanelet import Lanelet, LaneletNetwork, LaneletType, LineMarking

    segments = reference_line(sc.road)
    length = sum(seg.length for seg in segments)
    pts, hdg = sample_reference_line(segments, max(LANELET_STEP_M, length / MAX_LANELET_VERTICES))
    normal = np.column_stack([-np.sin(hdg), np.cos(hdg)])
    offsets = boundary_offsets(sc.road)
    n = sc.road.lane_count
    oncoming_next = sc.road.oncoming_lane_count > 0 and sc.road.median_width == 0
    left_opposite = oncoming_next and sc.road.driving_side == "right"  # the leftmost lane's left: the oncoming
    right_opposite = oncoming_next and sc.road.driving_side == "left"  # the rightmost lane's right: the oncoming
    net = LaneletNetwork()
    for k in range(n):
        right = pts + offsets[k] * normal
        left = pts + offsets[k + 1] * normal
        left_id = k + 2 if k + 1 < n or left_opposite else None
        right_id = k if k > 0 else (n + 1 if right_opposite else None)
        net.add_lanelet(
            Lanelet(
                left,
                (left + right) / 2.0,
                right,
                lanelet_id=k + 1,
                adjacent_left=left_id,
                adjacent_left_same_direction=(k + 1 < n) if left_id is not None else None,
                adjacent_right=right_id,
                adjacent_right_same_direction=(k > 0) if right_id is not None else None,
                line_marking_left_vertices=LineMarking.SOLID if k == n - 1 else LineMarking.DASHED,
                line_marking_right_vertices=LineMarking.SOLID if k == 0 else LineMarking.DASHED,
                lanelet_type={LaneletType.UNKNOWN},
            )
        )
    for lanelet in _oncoming_lanelets(sc.road, pts, normal):
        net.add_lanelet(lanelet)
    return net


def _oncoming_lanelets(road: Road, pts: np.ndarray, normal: np.ndarray) -> list[Any]:
    """The oncoming lanes' lanelets (see the module doc) on the reference line's samples ``pts`` (M, 2) with
    their left normals (metres)."""
    from commonroad.scenario.lanelet import Lanelet, LaneletType, LineMarking

    offsets = oncoming_boundary_offsets(road)
    n, m = road.lane_count, road.oncoming_lane_count
    touching = road.median_width == 0
    right_hand = road.driving_side == "right"
    out = []
    for k in range(m):
        # driving towards the line's start: in right-hand traffic the inner edge is the lanelet's left
        inner_edge = (pts + offsets[k] * normal)[::-1]
        outer_edge = (pts + offsets[k + 1] * normal)[::-1]
        inner = (n + k if k > 0 else (n if right_hand else 1)) if k > 0 or touching else None
        outer = n + 2 + k if k + 1 < m else None
        inner_kw = {"id": inner, "same": (k > 0) if inner is not None else None, "marking": k == 0}
        outer_kw = {"id": outer, "same": True if outer is not None else None, "marking": k == m - 1}
        left_kw, right_kw = (inner_kw, outer_kw) if right_hand else (outer_kw, inner_kw)
        left, right = (inner_edge, outer_edge) if right_hand else (outer_edge, inner_edge)
        out.append(
            Lanelet(
                left,
                (left + right) / 2.0,
                right,
                lanelet_id=n + 1 + k,
                adjacent_left=left_kw["id"],
                adjacent_left_same_direction=left_kw["same"],
                adjacent_right=right_kw["id"],
                adjacent_right_same_direction=right_kw["same"],
                line_marking_left_vertices=LineMarking.SOLID if left_kw["marking"] else LineMarking.DASHED,
                line_marking_right_vertices=LineMarking.SOLID if right_kw["marking"] else LineMarking.DASHED,
                lanelet_type={LaneletType.UNKNOWN},
            )
        )
    return out


def _obstacle(vehicle: Vehicle, states: dict[str, np.ndarray]) -> Any:
    from commonroad.geometry.shape import Rectangle
    from commonroad.prediction.prediction import TrajectoryPrediction
    from commonroad.scenario.obstacle import DynamicObstacle, ObstacleType
    from commonroad.scenario.state import CustomState, InitialState
    from commonroad.scenario.trajectory import Trajectory

    yaw = wrap_angle(states["yaw"])
    shape = Rectangle(vehicle.length, vehicle.width)
    cr_states = [
        CustomState(
            position=np.array([states["x"][i], states["y"][i]]),
            orientation=float(yaw[i]),
            velocity=float(states["speed"][i]),
            time_step=int(states["step"][i]),
        )
        for i in range(len(states["step"]))
    ]
    init = InitialState(
        position=cr_states[0].position,
        orientation=cr_states[0].orientation,
        velocity=cr_states[0].velocity,
        acceleration=0.0,
        yaw_rate=0.0,
        slip_angle=0.0,
        time_step=cr_states[0].time_step,
    )
    traj = Trajectory(cr_states[1].time_step, cr_states[1:])
    return DynamicObstacle(
        OBSTACLE_ID_BASE + vehicle.id,
        getattr(ObstacleType, _OBSTACLE_TYPE[vehicle.category]),
        shape,
        init,
        TrajectoryPrediction(traj, shape),
    )


def crash_point(sc: Scenario) -> tuple[np.ndarray, float, float]:
    """(point xy, heading rad, time s) the goal is placed past (see the module doc)."""
    ego = sc.ego.trajectory
    if sc.collision is None:
        s = ego.state_at(ego.t[-1])
        return np.array([s["x"], s["y"]]), s["yaw"], float(ego.t[-1])
    s = ego.state_at(sc.collision.time_s)
    xy = np.array([s["x"], s["y"]])
    if sc.collision.involves_ego and sc.collision.x is not None and sc.collision.y is not None:
        xy = np.array([sc.collision.x, sc.collision.y])  # a third-party crash point is not on the ego's way
    return xy, s["yaw"], float(sc.collision.time_s)


def _planning_problem(sc: Scenario, dt: float, last_step: int) -> Any:
    from commonroad.common.util import AngleInterval, Interval
    from commonroad.geometry.shape import Rectangle
    from commonroad.planning.goal import GoalRegion
    from commonroad.planning.planning_problem import PlanningProblem, PlanningProblemSet
    from commonroad.scenario.state import CustomState, InitialState

    ego = resample(sc.ego, dt)
    if len(ego["step"]) == 0:
        raise UserError("ego trajectory spans no CommonRoad time step")
    init = InitialState(
        position=np.array([ego["x"][0], ego["y"][0]]),
        orientation=float(wrap_angle(ego["yaw"][0])),
        velocity=float(ego["speed"][0]),
        acceleration=0.0,
        yaw_rate=0.0,
        slip_angle=0.0,
        time_step=int(ego["step"][0]),
    )
    xy, heading, t_crash = crash_point(sc)
    centre = xy + GOAL_AHEAD_M * np.array([math.cos(heading), math.sin(heading)])
    width = sc.road.lane_count * sc.road.lane_width
    k_crash = max(int(ego["step"][0]) + 1, math.floor(t_crash / dt) + 1)
    goal_state = CustomState(
        position=Rectangle(GOAL_LENGTH_M, width, center=centre, orientation=float(wrap_angle(heading))),
        time_step=Interval(k_crash, max(k_crash + 1, last_step + int(round(5.0 / dt)))),
        orientation=AngleInterval(float(wrap_angle(heading)) - math.pi / 4, float(wrap_angle(heading)) + math.pi / 4),
    )
    pp = PlanningProblem(OBSTACLE_ID_BASE + sc.ego.id, init, GoalRegion([goal_state]))
    return PlanningProblemSet([pp])


def build_commonroad(sc: Scenario, dt: float = COMMONROAD_DT_S) -> tuple[Any, Any, list[int]]:
    """(CommonRoad Scenario, PlanningProblemSet, ids of agents left out for spanning < 2 steps)."""
    from commonroad.scenario.scenario import Scenario as CRScenario
    from commonroad.scenario.scenario import ScenarioID

    if not (0.0 < dt <= 1.0):
        raise UserError(f"CommonRoad dt must be in (0, 1] s (got {dt})")
    cr = CRScenario(dt, ScenarioID(country_id="ZAM", map_name="DeepCrashTest", map_id=1, configuration_id=1))
    ego = resample(sc.ego, dt)
    if len(ego["step"]) == 0:
        raise UserError(
            f"ego trajectory spans no CommonRoad time step (samples {sc.ego.trajectory.t[0]:g}-"
            f"{sc.ego.trajectory.t[-1]:g} s, start delay {sc.ego.start_delay_s:g} s, step {dt:g} s)"
        )
    cr.add_objects(_lanelet_network(sc))
    skipped: list[int] = []
    last_step = int(ego["step"][-1])
    for agent in sc.agents:
        states = resample(agent, dt)
        if len(states["step"]) < 2:
            skipped.append(agent.id)
            continue
        last_step = max(last_step, int(states["step"][-1]))
        cr.add_objects(_obstacle(agent, states))
    return cr, _planning_problem(sc, dt, last_step), skipped


def write_commonroad(
    sc: Scenario, path: str | os.PathLike[str], dt: float = COMMONROAD_DT_S, force: bool = False
) -> tuple[Path, list[int]]:
    """Write ``sc`` as a CommonRoad XML file (validity check on). Returns (path, agents left out)."""
    from commonroad.common.file_writer import CommonRoadFileWriter, OverwriteExistingFile
    from commonroad.scenario.scenario import Location, Tag

    cr, pps, skipped = build_commonroad(sc, dt)
    writer = CommonRoadFileWriter(
        cr,
        pps,
        author="deepcrashtest",
        affiliation="DeepCrashTest",
        source=f"DeepCrashTest scenario {sc.name} ({sc.source.kind})",
        tags={Tag.CRITICAL},
        location=Location(),  # unknown place (geo name id -999); explicit, so no warning
    )
    with atomic_path(path, force=force) as tmp, contextlib.redirect_stdout(io.StringIO()):
        # commonroad-io prints notes ("Replace file ...") on stdout, which is ours (--json)
        writer.write_to_file(str(tmp), OverwriteExistingFile.ALWAYS, check_validity=True)
    return Path(path), skipped


def ego_collision_steps(cr_scenario: Any, ego: Vehicle, dt: float | None = None) -> list[int]:
    """Time steps at which the ego's recorded box collides with an obstacle of ``cr_scenario``.

    Uses the CommonRoad drivability checker (``create_collision_checker`` on the scenario, then one
    oriented box per ego step against the checker's time slice).
    """
    # imported by name: commonroad_dc's pycrcc.pyi stub is not valid Python syntax for mypy
    pycrcc = importlib.import_module("commonroad_dc.pycrcc")
    dispatch = importlib.import_module("commonroad_dc.collision.collision_detection.pycrcc_collision_dispatch")

    step_dt = float(cr_scenario.dt) if dt is None else dt
    checker = dispatch.create_collision_checker(cr_scenario)
    states = resample(ego, step_dt)
    hits = []
    for k, x, y, yaw in zip(states["step"], states["x"], states["y"], states["yaw"], strict=True):
        box = pycrcc.RectOBB(ego.length / 2.0, ego.width / 2.0, float(yaw), float(x), float(y))
        if checker.time_slice(int(k)).collide(box):
            hits.append(int(k))
    return hits
