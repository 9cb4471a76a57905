"""What a search writes: results.csv, variant Scenario files, the start-position plot, the video."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from deepcrashtest.errors import ScenarioError
from deepcrashtest.fileio import atomic_write_text
from deepcrashtest.scenario import MAX_NAME_CHARS, Provenance, Scenario, Trajectory, format_validation_error
from deepcrashtest.search.evaluate import OUTCOME_FIELDS
from deepcrashtest.search.space import SearchSpace
from deepcrashtest.search.table import Table, column


def results_table(
    space: SearchSpace, theta: np.ndarray, out: dict[str, np.ndarray], methods: list[str], iters: list[int], safe
) -> Table:
    """One row per simulated variant: id, method, iteration, per-method simulation number, params, outcome."""
    method = np.array(methods, dtype=str) if methods else np.zeros(0, dtype=str)
    simulation = np.zeros(len(method), dtype=np.int64)
    for m in dict.fromkeys(methods):  # the running count within each method (pandas' groupby().cumcount() + 1)
        rows = np.flatnonzero(method == m)
        simulation[rows] = np.arange(1, len(rows) + 1)
    table: Table = {
        "variant": np.arange(len(method), dtype=np.int64),
        "method": method,
        "iteration": np.asarray(iters, dtype=np.int64).reshape(len(method)),
        "simulation": simulation,
        "safe": np.asarray(safe, bool).reshape(len(method)),
        "change_m": np.asarray(out["change"], float),
    }
    for k in OUTCOME_FIELDS:
        table[k] = np.asarray(out[k])
    th = np.asarray(theta, float).reshape(len(method), len(space.names()))
    for j, name in enumerate(space.names()):
        table[name] = th[:, j]
    return table


def variant_scenario(
    scenario: Scenario,
    space: SearchSpace,
    theta: np.ndarray,
    variant: int,
    meta: dict[str, Any],
    kinematics: tuple[np.ndarray, ...] | None = None,
) -> Scenario:
    """The scenario with the ego's trajectory (and spline) replaced by variant ``theta``'s.

    Provenance records the variant's parameters, the search settings (``meta``) and the seed.
    ``kinematics``: the variant's trajectory arrays where computed already (:meth:`SearchSpace.variant_kinematics`).
    Raises ScenarioError when the variant breaks the Scenario's physical limits.
    """
    name = f"{scenario.name}_variant{variant:04d}"
    try:
        traj = space.variant_trajectory(theta) if kinematics is None else Trajectory.from_arrays(*kinematics)
        spline = space.variant_spline(theta)
    except ValidationError as exc:
        raise ScenarioError(f"variant {variant}: ego.{format_validation_error(exc)}") from None
    # the Scenario's physics check, which the ego fails first (its other fields are valid, the name too when not
    # too long): the same message without validating the whole scenario (~1 ms; most variants a search tries on
    # a jerky extracted ego fail here)
    if scenario.stage == "processed" and len(name) <= MAX_NAME_CHARS:
        problem = traj.accel_problem("ego")
        if problem is not None:
            raise ScenarioError(f"variant {variant}: (root): {problem}")
    ego = scenario.ego.model_copy(update={"trajectory": traj, "spline": spline})
    params = {
        "variant": int(variant),
        "source_scenario": scenario.name,
        "d_lon_m": float(theta[0]),
        "d_lat_m": float(theta[1]),
        "control_point_noise_m": [round(float(v), 6) for v in theta[2:]],
        "change_m": float(space.change(theta)[0]),
        **meta,
    }
    prov = Provenance(
        command="search",
        parameters=params,
        seed=int(meta.get("seed", 0)),
        history=[
            *scenario.provenance.history,
            f"search variant {variant}: ego start moved ({theta[0]:.3f}, {theta[1]:.3f}) m (forward, left), "
            f"control points perturbed (RMS {float(np.sqrt(np.mean(theta[2:] ** 2))) if len(theta) > 2 else 0:.3f} m)",
        ],
    )
    # a safe variant's ego touches nobody; a third-party crash (two agents, replayed) still happens in it
    crash = scenario.collision if scenario.collision is not None and not scenario.collision.involves_ego else None
    try:
        return scenario.evolve(name=name, ego=ego, collision=crash, provenance=prov)
    except ScenarioError as exc:
        raise ScenarioError(f"variant {variant}: {str(exc).removeprefix('scenario: ')}") from None


def write_variants(
    scenario: Scenario,
    space: SearchSpace,
    table: Mapping[str, Any],
    theta: np.ndarray,
    folder: Path,
    meta: dict[str, Any],
    limit: int,
    force: bool,
) -> tuple[list[str], dict[int, str], Scenario | None]:
    """Write the ``limit`` safe variants with the least change as Scenario files.

    A variant that breaks the Scenario's physical limits (the simulator drove it, but its path asks e.g. an
    acceleration no vehicle has) is a result, not an error: it is recorded in the problems and skipped.
    Returns (paths written, {variant: problem}, the first valid variant's Scenario or None). The files are
    written by a few threads while the next variants are built (each write waits ~10 ms for its fsync).
    """
    from concurrent.futures import ThreadPoolExecutor

    safe = np.flatnonzero(column(table, "safe"))
    variant, method = column(table, "variant")[safe], column(table, "method")[safe]
    order = np.lexsort((variant, column(table, "change_m")[safe]))  # least change first, then the lowest id
    saved: list[Any] = []
    problems: dict[int, str] = {}
    best: Scenario | None = None
    kinematics = _kinematics(space, theta, variant[order], limit)
    candidates = zip(variant[order].tolist(), method[order].tolist(), kinematics, strict=True)
    texts = SharedAgentsJson(scenario)
    with ThreadPoolExecutor(max_workers=4) as pool:
        for vid, m, kin in candidates:
            if len(saved) >= limit and best is not None:
                break
            try:
                sc = variant_scenario(scenario, space, theta[int(vid)], int(vid), {**meta, "method": m}, kin)
            except ScenarioError as exc:
                problems[int(vid)] = str(exc)
                continue
            best = best or sc
            if len(saved) < limit:
                path = folder / f"variant_{int(vid):04d}.json"
                saved.append(pool.submit(atomic_write_text, path, texts.text(sc), force))
        paths = [str(f.result()) for f in saved]
    return paths, problems, best


class SharedAgentsJson:
    """Variant files' text (:meth:`Scenario.to_json`, the same characters) with the source scenario's agents
    serialised once: a variant changes the ego and shares the agents' models, most of a file (KITTI 0003: 9 agents,
    ~1.4 of a file's ~1.6 ms of serialising, 32 files a search)."""

    _KEY = '\n "agents": []'  # a top-level key: one space of indent (deeper keys have more; strings hold no newline)

    def __init__(self, scenario: Scenario) -> None:
        self.agents = scenario.agents
        self.fragment: str | None = None
        whole, parts = scenario.to_json(), self._around(scenario)
        if parts is not None and whole.startswith(parts[0]) and whole.endswith(parts[1]):
            self.fragment = whole[len(parts[0]) : len(whole) - len(parts[1])]

    def text(self, sc: Scenario) -> str:
        """``sc.to_json()``: ``sc``'s own fields with the shared agents' text where ``sc`` holds those very agents."""
        same = len(sc.agents) == len(self.agents) and all(a is b for a, b in zip(sc.agents, self.agents, strict=True))
        parts = self._around(sc) if same and self.fragment is not None else None
        if parts is None or self.fragment is None:
            return sc.to_json()
        return parts[0] + self.fragment + parts[1]

    @classmethod
    def _around(cls, sc: Scenario) -> tuple[str, str] | None:
        """The JSON of ``sc`` without agents, cut where its agents' list goes (before ``[]``, after it)."""
        text = sc.model_copy(update={"agents": []}).to_json()
        i = text.find(cls._KEY)
        if i < 0 or text.find(cls._KEY, i + 1) >= 0:
            return None
        i += len(cls._KEY) - 2
        return text[:i], text[i + 2 :]


def _kinematics(
    space: SearchSpace, theta: np.ndarray, variants: np.ndarray, limit: int
) -> Iterator[tuple[np.ndarray, ...]]:
    """The trajectory arrays of ``variants`` in order, computed a block at a time as they are asked for (the first
    block: the ``limit`` files and a quarter more, for variants outside the physical limits)."""
    block = max(1, limit + limit // 4)
    for lo in range(0, len(variants), block):
        yield from space.variant_kinematics(theta[variants[lo : lo + block]])


def write_video(
    original: Scenario,
    best: Scenario,
    path: Path,
    controller: str,
    seed: int,
    force: bool,
    duration: float | None = None,
    label: str = "best safe variant",
) -> str | None:
    """Bird's-eye H.264 video: the original run (left) beside the best safe variant (right).

    Both are simulated with ``deepcrashtest.sim.simulate`` and drawn by ``deepcrashtest.viz.birdseye``.
    """
    import cv2

    from deepcrashtest.sim import simulate
    from deepcrashtest.viz.birdseye import FPS, render_frames
    from deepcrashtest.viz.h264 import h264_writer

    runs = [simulate(sc, controller, seed=seed, duration=duration) for sc in (original, best)]
    stride = max(1, int(round(1.0 / (FPS * float(runs[0].dt)))))
    w, h = 640, 360
    rate = round(1.0 / (stride * float(runs[0].dt)))
    with h264_writer(path, 2 * w, h, rate, force, crf=26) as write:
        left, right = render_frames(original, runs[0], stride), render_frames(best, runs[1], stride)
        last: list[Any] = [None, None]
        while True:
            pair = [next(left, None), next(right, None)]
            if pair[0] is None and pair[1] is None:
                break
            last = [p if p is not None else q for p, q in zip(pair, last, strict=True)]
            tiles = [cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA) for img in last]
            for img, text in zip(tiles, ("original", label), strict=True):
                cv2.putText(img, text, (10, h - 40), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
            write(np.hstack(tiles))
    return str(path)


def write_summary(summary: dict[str, Any], path: Path, force: bool) -> Path:
    import json

    return atomic_write_text(path, json.dumps(summary, indent=1, allow_nan=False, default=_plain) + "\n", force=force)


def _plain(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(type(o).__name__)
