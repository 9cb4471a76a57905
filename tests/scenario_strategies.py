"""Hypothesis strategies for Scenarios and the properties of issue 18, shared by the tests and the fuzz bench.

Property: any scenario the schema accepts (processed or raw) either processes and simulates or gives a clear
error (a UserError / ScenarioError, exit 2 at the CLI), never an internal one; anything else is refused on load
with a ScenarioError.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
from hypothesis import strategies as st

from deepcrashtest.errors import UserError
from deepcrashtest.scenario import MAX_ACCEL_MPS2, MAX_COORD_M, MAX_SPEED_MPS, ROAD_USER_CATEGORIES, Scenario

COORD = st.floats(-MAX_COORD_M, MAX_COORD_M, allow_nan=False)
SMALL = st.floats(-300.0, 300.0, allow_nan=False)


@st.composite
def trajectories(draw: st.DrawFn, t0: float, processed: bool, far: bool) -> dict[str, Any]:
    """A trajectory dict: 1-25 samples, strictly increasing t, speeds that keep the acceleration limit when
    ``processed``; positions anywhere in the physical range when ``far`` (teleports included)."""
    n = draw(st.integers(1, 25))
    dts = draw(st.lists(st.floats(0.01, 1.0), min_size=n - 1, max_size=n - 1))
    t = [t0]
    for d in dts:
        t.append(t[-1] + d)
    pos = COORD if far else SMALL
    x0, y0 = draw(pos), draw(pos)
    if draw(st.booleans()):  # a plausible drive: a speed profile integrated along a heading
        v = [draw(st.floats(0.0, MAX_SPEED_MPS))]
        for d in dts:
            dv = draw(st.floats(-1.0, 1.0)) * MAX_ACCEL_MPS2 * d * 0.99
            v.append(min(MAX_SPEED_MPS, max(0.0, v[-1] + dv)))
        yaw0 = draw(st.floats(-math.pi, math.pi))
        yaw_rate = draw(st.floats(-1.0, 1.0))
        yaw = [yaw0 + yaw_rate * (ti - t0) for ti in t]
        x, y = [x0], [y0]
        for i, d in enumerate(dts):
            x.append(x[-1] + v[i] * d * math.cos(yaw[i]))
            y.append(y[-1] + v[i] * d * math.sin(yaw[i]))
        x = [min(MAX_COORD_M, max(-MAX_COORD_M, c)) for c in x]
        y = [min(MAX_COORD_M, max(-MAX_COORD_M, c)) for c in y]
    else:  # arbitrary samples: positions, headings and speeds that need not agree
        x = draw(st.lists(pos, min_size=n, max_size=n))
        y = draw(st.lists(pos, min_size=n, max_size=n))
        yaw = draw(st.lists(st.floats(-20.0, 20.0), min_size=n, max_size=n))
        v = draw(st.lists(st.floats(0.0, MAX_SPEED_MPS), min_size=n, max_size=n))
        if processed:
            v = [v[0]] * n
    return {"t": t, "x": x, "y": y, "yaw": yaw, "speed": v}


@st.composite
def vehicles(draw: st.DrawFn, vid: int, processed: bool, far: bool) -> dict[str, Any]:
    t0 = 0.0 if vid == 0 else draw(st.floats(0.0, 5.0))
    first = draw(st.integers(0, 200))
    return {
        "id": vid,
        "category": draw(st.sampled_from(ROAD_USER_CATEGORIES)),
        "length": draw(st.floats(0.1, 30.0)),
        "width": draw(st.floats(0.1, 30.0)),
        "height": draw(st.floats(0.1, 30.0)),
        "first_frame": first,
        "last_frame": first + draw(st.integers(0, 200)),
        "start_delay_s": draw(st.sampled_from([0.0, 0.0, 0.5, 3.0])),
        "trajectory": draw(trajectories(t0, processed, far)),
    }


@st.composite
def scenario_dicts(draw: st.DrawFn, stage: str = "processed") -> dict[str, Any]:
    """A decoded Scenario file of the given stage (schema-valid in its types and ranges; the cross-field
    checks, e.g. collision participants, may still refuse it)."""
    processed = stage == "processed"
    far = draw(st.booleans())
    n_agents = draw(st.integers(0, 3))
    ego = draw(vehicles(0, processed, far))
    agents = [draw(vehicles(i + 1, processed, far)) for i in range(n_agents)]
    road_x = draw(st.lists(COORD if far else SMALL, min_size=2, max_size=6))
    lane_count = draw(st.integers(1, 4))
    data: dict[str, Any] = {
        "schema_version": "1.1",
        "name": draw(st.text(st.characters(codec="utf-8", exclude_categories=["Cc", "Cs"]), min_size=1, max_size=30)),
        "stage": stage,
        "source": {
            "kind": "synthetic",
            "path": "fuzz",
            "fps": draw(st.sampled_from([5.0, 10.0, 25.0, 29.97, 60.0])),
            "frame_count": draw(st.integers(0, 500)),
            "width": 1280,
            "height": 720,
            "time_offset_s": draw(st.floats(-10.0, 10.0)),
        },
        "camera": {"fx": 1000.0, "fy": 1000.0, "cx": 640.0, "cy": 360.0},
        "ego": ego,
        "agents": agents,
        "road": {
            "centerline_x": road_x,
            "centerline_y": draw(st.lists(COORD if far else SMALL, min_size=len(road_x), max_size=len(road_x))),
            "lane_count": lane_count,
            "ego_lane": draw(st.integers(0, lane_count - 1)),
            "lane_width": draw(st.floats(1.0, 20.0)),
            "oncoming_lane_count": draw(st.integers(0, 3)),
            "median_width": draw(st.sampled_from([0.0, 0.5, 12.0])),
            "driving_side": draw(st.sampled_from(["right", "left"])),
        },
    }
    if agents and draw(st.booleans()):
        t_end = ego["trajectory"]["t"][-1]
        data["collision"] = {
            "time_s": draw(st.floats(0.0, max(t_end, 0.01))),
            "agent_id": draw(st.integers(1, n_agents)),
            "source": "user",
        }
    if draw(st.booleans()):  # a variable-frame-rate video's own frame times (schema 1.6)
        gaps = draw(st.lists(st.floats(0.005, 0.5), min_size=1, max_size=60))
        data["source"]["frame_times"] = np.concatenate([[0.0], np.cumsum(gaps)]).tolist()
    return data


JSON_LEAF = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**20), 10**20),
    st.floats(allow_nan=False, allow_infinity=False),
    st.text(max_size=8),
)
JSON_VALUE = st.recursive(
    JSON_LEAF, lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=5), c, max_size=3)
)


@st.composite
def mutated_dicts(draw: st.DrawFn, base: dict[str, Any]) -> dict[str, Any]:
    """``base`` with 1-3 values anywhere in the tree replaced by arbitrary JSON (or deleted)."""
    data = json.loads(json.dumps(base))
    for _ in range(draw(st.integers(1, 3))):
        node: Any = data
        path: list[Any] = []
        while isinstance(node, dict | list) and node and (not path or draw(st.booleans())):
            key = draw(st.sampled_from(sorted(node) if isinstance(node, dict) else list(range(len(node)))))
            path.append(key)
            parent, node = node, node[key]
        if not path:
            continue
        if isinstance(parent, dict) and draw(st.integers(0, 4)) == 0:
            del parent[path[-1]]
        else:
            parent[path[-1]] = draw(JSON_VALUE)
    return data


# --------------------------------------------------------------------------- the properties
def load_or_refuse(data: Any) -> Scenario | None:
    """A decoded file is a Scenario or a ScenarioError (also through a JSON round trip), nothing else."""
    try:
        sc = Scenario.from_dict(data, origin="fuzz")
    except UserError:
        return None
    again = Scenario.from_dict(json.loads(sc.to_json()), origin="fuzz")
    assert again == sc
    return sc


def simulate_or_refuse(sc: Scenario) -> None:
    """Simulate once (AEB, sensors on) and a batch of three shifted starts: results or a UserError."""
    from deepcrashtest.sim import simulate, simulate_batch

    duration = min(sc.duration(), 4.0) if sc.duration() > 0 else None
    try:
        res = simulate(sc, controller="aeb", duration=duration)
        assert np.isfinite(res.times).all()
        batch = simulate_batch(sc, np.array([[0.0, 0.0], [-2.0, 1.0], [3.0, -1.0]]), duration=duration)
        assert len(batch) == 3
    except UserError:
        return


def process_or_refuse(raw: Scenario) -> Scenario | None:
    """Stage 2 on a raw scenario: a valid processed Scenario or a UserError."""
    from deepcrashtest.trajectory.pipeline import process_scenario

    try:
        sc = process_scenario(raw)
    except UserError:
        return None
    assert sc.stage == "processed"
    Scenario.from_dict(json.loads(sc.to_json()), origin="stage 2 output")  # valid as a file too
    return sc
