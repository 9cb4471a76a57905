"""ASAM OpenSCENARIO 1.2 (``scenario.xosc``) from a Scenario, via scenariogeneration.

What the file holds:

* ``RoadNetwork/LogicFile``: the OpenDRIVE road written beside it (``road.xodr``, see
  :mod:`deepcrashtest.export.opendrive`). Both files use the Scenario's world frame (x forward,
  y left, metres, origin at the ego's start), so world positions need no transformation.
* One ``Vehicle`` entity per vehicle (``Ego``, ``Agent<id>``) with its bounding box and class
  (car, van, truck, bus, motorbike, bicycle; a two-wheeler includes its rider). The entity reference
  point is, as OpenSCENARIO defines it, the rear axle projected on the ground; it sits
  ``REAR_AXLE_FRACTION * length`` behind the box centre, so ``BoundingBox/Center/@x`` is that
  distance and every position written is the box centre (Scenario trajectory point) moved back along
  the heading by it. A pedestrian is a ``Pedestrian`` entity (category pedestrian, mass
  ``PEDESTRIAN_MASS_KG``) whose reference point is its box centre on the ground.
* ``ParameterDeclarations``: ``EgoStartDx``, ``EgoStartDy`` (metres, world frame, default 0):
  a shift of the ego's start (and of its whole recorded path, when it follows one). The search's
  variants are written against them by :func:`write_parameter_distribution`.
* ``Init``: every vehicle present at t = 0 is teleported to its first pose and given its first
  speed (``AbsoluteSpeedAction``, step). A vehicle that appears later (``start_delay_s`` or a first
  sample after t = 0) is removed at t = 0 (``DeleteEntityAction``) and added at its entry pose
  when it appears (``AddEntityAction``), so it is never a parked ghost on the road before then.
* One ``ManeuverGroup`` per vehicle: a ``FollowTrajectoryAction`` on a timed polyline of every
  trajectory sample (``Timing`` absolute, scale 1, offset 0: vertex times are simulation
  seconds = scenario time; the video's time is t - ``source.time_offset_s``, ``Scenario.video_time``),
  ``FollowingMode`` position. Start triggers are ``SimulationTime greaterOrEqual t``
  (t = 0, or the entry time of a late vehicle: ``greaterThan 0`` would start one step late).
* With ``ego_free`` the ego gets its start pose and speed only, no trajectory: the user's system
  under test drives it.
* ``StopTrigger``: simulation time >= the Scenario's duration.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from deepcrashtest.errors import UserError
from deepcrashtest.fileio import atomic_path
from deepcrashtest.scenario import MAX_ACCEL_MPS2, MAX_SPEED_MPS, Scenario, Vehicle

OSC_MINOR_VERSION = 2
#: Rear axle behind the box centre, as a fraction of the vehicle length (wheelbase ~0.6 length).
REAR_AXLE_FRACTION = 0.3
EGO_NAME = "Ego"
PEDESTRIAN_MASS_KG = 75.0
#: Parameters declared in every exported scenario (metres, world frame), all default 0.
EGO_START_PARAMETERS = ("EgoStartDx", "EgoStartDy")

_CATEGORY = {
    "car": "car",
    "van": "van",
    "truck": "truck",
    "bus": "bus",
    "motorcycle": "motorbike",
    "bicycle": "bicycle",
}


def entity_name(vehicle: Vehicle, ego_id: int) -> str:
    """``Ego`` for the ego, ``Agent<id>`` for the others."""
    return EGO_NAME if vehicle.id == ego_id else f"Agent{vehicle.id}"


def entry_time(vehicle: Vehicle) -> float:
    """Seconds at which the vehicle enters: the later of its start delay and its first sample."""
    return max(float(vehicle.start_delay_s), float(vehicle.trajectory.t[0]))


def exported_samples(vehicle: Vehicle) -> dict[str, np.ndarray]:
    """The trajectory samples written as polyline vertices: all samples from the entry time on.

    If the entry time falls between samples, the state there is interpolated and comes first.
    """
    a = vehicle.trajectory.arrays()
    t0 = entry_time(vehicle)
    keep = a["t"] > t0 + 1e-9
    out = {k: v[keep] for k, v in a.items()}
    first = vehicle.trajectory.state_at(t0)
    return {k: np.concatenate([[first[k]], out[k]]) for k in out}


def _fmt(value: float) -> str:
    return f"{value:.6f}"


def _shifted(value: float, parameter: str) -> str:
    """An OpenSCENARIO expression: ``value`` plus a declared parameter."""
    sign = "-" if value < 0 else "+"
    return f"${{${parameter} {sign} {_fmt(abs(value))}}}"


def _rear_axle_back(vehicle: Vehicle) -> float:
    """Metres from the box centre back to the entity's reference point (0 for a pedestrian)."""
    return 0.0 if vehicle.category == "pedestrian" else REAR_AXLE_FRACTION * vehicle.length


def _reference_points(vehicle: Vehicle, x: np.ndarray, y: np.ndarray, yaw: np.ndarray) -> tuple[Any, Any]:
    back = _rear_axle_back(vehicle)
    return x - back * np.cos(yaw), y - back * np.sin(yaw)


def _world_positions(vehicle: Vehicle, samples: dict[str, np.ndarray], shift: bool) -> list[Any]:
    from scenariogeneration import xosc

    rx, ry = _reference_points(vehicle, samples["x"], samples["y"], samples["yaw"])
    out = []
    for xi, yi, hi in zip(rx, ry, samples["yaw"], strict=True):
        if shift:
            px: Any = _shifted(float(xi), "EgoStartDx")
            py: Any = _shifted(float(yi), "EgoStartDy")
        else:
            px, py = float(xi), float(yi)
        out.append(xosc.WorldPosition(px, py, 0.0, float(hi), 0.0, 0.0))
    return out


def _vehicle_entity(vehicle: Vehicle, name: str) -> Any:
    from scenariogeneration import xosc

    if vehicle.category == "pedestrian":
        return _pedestrian_entity(vehicle, name)
    back = _rear_axle_back(vehicle)
    wheel = 0.6 if vehicle.category not in ("motorcycle", "bicycle") else 0.65
    bbox = xosc.BoundingBox(vehicle.width, vehicle.length, vehicle.height, back, 0.0, vehicle.height / 2.0)
    track = max(0.1, vehicle.width - 0.3)
    front = xosc.Axle(0.5, wheel, track, 2.0 * back, wheel / 2.0)
    rear = xosc.Axle(0.0, wheel, track, 0.0, wheel / 2.0)
    veh = xosc.Vehicle(
        name,
        getattr(xosc.VehicleCategory, _CATEGORY[vehicle.category]),
        bbox,
        front,
        rear,
        MAX_SPEED_MPS,
        MAX_ACCEL_MPS2,
        MAX_ACCEL_MPS2,
    )
    veh.add_property("deepcrashtest_id", str(vehicle.id))
    veh.add_property("deepcrashtest_role", "ego" if name == EGO_NAME else "agent")
    return veh


def _pedestrian_entity(vehicle: Vehicle, name: str) -> Any:
    from scenariogeneration import xosc

    bbox = xosc.BoundingBox(vehicle.width, vehicle.length, vehicle.height, 0.0, 0.0, vehicle.height / 2.0)
    ped = xosc.Pedestrian(name, PEDESTRIAN_MASS_KG, xosc.PedestrianCategory.pedestrian, bbox, model="pedestrian")
    ped.add_property("deepcrashtest_id", str(vehicle.id))
    ped.add_property("deepcrashtest_role", "agent")
    return ped


def _time_trigger(name: str, t: float, point: str = "start") -> Any:
    from scenariogeneration import xosc

    cond = xosc.SimulationTimeCondition(float(t), xosc.Rule.greaterOrEqual)
    return xosc.ValueTrigger(name, 0, xosc.ConditionEdge.none, cond, point)


def _speed_action(speed: float) -> Any:
    from scenariogeneration import xosc

    dyn = xosc.TransitionDynamics(xosc.DynamicsShapes.step, xosc.DynamicsDimension.time, 0)
    return xosc.AbsoluteSpeedAction(float(speed), dyn)


def build_openscenario(sc: Scenario, road_file: str = "road.xodr", ego_free: bool = False) -> Any:
    """The scenariogeneration ``xosc.Scenario`` of ``sc`` (see the module doc)."""
    from scenariogeneration import xosc

    params = xosc.ParameterDeclarations()
    for p in EGO_START_PARAMETERS:
        params.add_parameter(xosc.Parameter(p, xosc.ParameterType.double, "0"))
    entities = xosc.Entities()
    init = xosc.Init()
    act = xosc.Act("replay", _time_trigger("replay_start", 0.0))
    groups = 0
    for veh in sc.vehicles():
        name = entity_name(veh, sc.ego.id)
        is_ego = veh.id == sc.ego.id
        entities.add_scenario_object(name, _vehicle_entity(veh, name))
        samples = exported_samples(veh)
        positions = _world_positions(veh, samples, shift=is_ego)
        t_enter = entry_time(veh)
        late = t_enter > 0.0 and not is_ego
        if late:
            init.add_global_action(xosc.DeleteEntityAction(name))
        else:
            init.add_init_action(name, xosc.TeleportAction(positions[0]))
            init.add_init_action(name, _speed_action(samples["speed"][0]))
        if is_ego and ego_free:
            continue
        if len(samples["t"]) < 2 and not late:
            continue  # a single sample: the vehicle only stands at its start
        event = xosc.Event(f"{name}_follow", xosc.Priority.override)
        if late:
            event.add_action(f"{name}_appear", xosc.AddEntityAction(name, positions[0]))
            event.add_action(f"{name}_entry_speed", _speed_action(samples["speed"][0]))
        if len(samples["t"]) >= 2:
            traj = xosc.Trajectory(f"{name}_trajectory", False)
            traj.add_shape(xosc.Polyline([float(t) for t in samples["t"]], positions))
            follow = xosc.FollowTrajectoryAction(
                traj, xosc.FollowingMode.position, xosc.ReferenceContext.absolute, 1, 0
            )
            event.add_action(f"{name}_trajectory", follow)
        event.add_trigger(_time_trigger(f"{name}_start", t_enter))
        maneuver = xosc.Maneuver(f"{name}_maneuver")
        maneuver.add_event(event)
        group = xosc.ManeuverGroup(f"{name}_group")
        group.add_actor(name)
        group.add_maneuver(maneuver)
        act.add_maneuver_group(group)
        groups += 1
    board = xosc.StoryBoard(init, _time_trigger("end", sc.duration(), "stop"))
    if groups:  # nobody moves (single samples, or --ego-free alone): the Init is the scenario, no Story
        story = xosc.Story("crash")
        story.add_act(act)
        board.add_story(story)
    return xosc.Scenario(
        sc.name,
        "deepcrashtest",
        params,
        entities,
        board,
        xosc.RoadNetwork(roadfile=road_file),
        xosc.Catalog(),
        osc_minor_version=OSC_MINOR_VERSION,
    )


def write_openscenario(
    sc: Scenario,
    path: str | os.PathLike[str],
    road_file: str = "road.xodr",
    ego_free: bool = False,
    force: bool = False,
) -> Path:
    """Write ``sc`` as an OpenSCENARIO 1.2 file (``road_file``: the .xodr path, relative to it)."""
    osc = build_openscenario(sc, road_file=road_file, ego_free=ego_free)
    with atomic_path(path, force=force) as tmp:
        osc.write_xml(str(tmp))
    return Path(path)


def declared_parameters(xosc_path: str | os.PathLike[str]) -> dict[str, str]:
    """Name -> default value of the top-level ParameterDeclarations of an .xosc file."""
    from lxml import etree

    try:
        root = etree.parse(str(xosc_path)).getroot()
    except (OSError, etree.XMLSyntaxError) as exc:
        raise UserError(f"{xosc_path}: cannot read OpenSCENARIO file ({exc})") from None
    return {p.get("name"): p.get("value") for p in root.findall("ParameterDeclarations/ParameterDeclaration")}


def write_parameter_distribution(
    scenario_xosc_path: str | os.PathLike[str],
    variants: list[dict[str, float]],
    path: str | os.PathLike[str],
    force: bool = False,
) -> Path:
    """Write the search's variants as an OpenSCENARIO 1.2 ParameterValueDistribution file.

    One ``ParameterValueSet`` per variant (a deterministic multi-parameter distribution) against
    ``scenario_xosc_path``, referenced relative to ``path``'s folder. Every key must be a parameter
    declared in that scenario (e.g. ``EgoStartDx``, ``EgoStartDy``, metres) and every value finite.
    """
    from scenariogeneration import xosc

    declared = declared_parameters(scenario_xosc_path)
    if not variants:
        raise UserError("parameter distribution: no variants given")
    dist = xosc.DeterministicMultiParameterDistribution()
    for i, variant in enumerate(variants):
        if not variant:
            raise UserError(f"parameter distribution: variant {i} sets no parameter")
        value_set = xosc.ParameterValueSet()
        for name, value in variant.items():
            if name not in declared:
                raise UserError(
                    f"parameter distribution: variant {i} sets {name!r}, which {scenario_xosc_path} does not "
                    f"declare (declared: {', '.join(sorted(declared))})"
                )
            if not math.isfinite(float(value)):
                raise UserError(f"parameter distribution: variant {i} sets {name} to {value}")
            value_set.add_parameter(name, repr(float(value)))
        dist.add_value_set(value_set)
    deterministic = xosc.Deterministic()
    deterministic.add_multi_distribution(dist)
    target = Path(path)
    rel = os.path.relpath(Path(scenario_xosc_path).resolve(), target.resolve().parent)
    pvd = xosc.ParameterValueDistribution(
        "DeepCrashTest search variants", "deepcrashtest", rel, deterministic, osc_minor_version=OSC_MINOR_VERSION
    )
    with atomic_path(target, force=force) as tmp:
        pvd.write_xml(str(tmp))
    return target
