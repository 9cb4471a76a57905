"""Simulate variants: in-process (vectorised), on a local process pool, or on Ray.

Every engine cuts the variants into the same fixed-size chunks and simulates each chunk with
``deepcrashtest.sim.simulate_batch`` under the same seed, so the results do not depend on the
engine or the number of workers. With the replay controller (no sensor noise; every variant's
outcome depends on its own parameters alone) the chunks are instead sized to keep every worker
equally busy, at most ``chunk`` variants each.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepcrashtest.errors import UserError
from deepcrashtest.scenario import Scenario
from deepcrashtest.search.space import SearchSpace

#: Default variants per simulator call. The chunk size is a setting of the search, never derived
#: from the worker count, so that every engine simulates exactly the same batches (the sensor
#: noise of a batch depends on its size).
CHUNK = 512
#: With the replay controller (no sensor noise, so the cut does not change any result): variants per
#: simulator call at most, the batch cut evenly over the workers. Larger calls spread the per-call
#: costs (path tables, agent arrays) over more variants; ~0.15 GB of arrays per 1,000 variants.
REPLAY_CHUNK = 2048
#: Per-variant outcome columns returned by the simulator, in results.csv order.
OUTCOME_FIELDS = ("collided", "collision_time", "min_distance", "min_ttc", "robustness", "aeb_time", "delta_v_ego")
#: Below this many variant-steps (variants x the world's time steps, ~1.0-2.0 us of CPU each on the
#: crash clips) a call simulates in this process instead of on the worker pool: forking the workers, their cold
#: per-process costs and shipping the results cost more than the second core saves (chosen on the crash clips
#: ccd_000721 and dad_000487 at 129-2,001 variants: docs/notes/searchfps14.md). The results do not change: the
#: same chunks are simulated, one after the other.
IN_PROCESS_WORK = 100_000
ENGINES = ("local", "ray")
MAX_WORKERS = 1024  # processes: more than any machine's cores (the process pool's queues take a C int)


def check_workers(workers: int) -> None:
    """Refuse a ``--workers`` value outside 1-MAX_WORKERS (one-line UserError)."""
    if not 1 <= workers <= MAX_WORKERS:
        raise UserError(f"--workers must be 1-{MAX_WORKERS} (got {workers})")


def simulate_chunk(
    scenario_json: str,
    offsets: np.ndarray,
    paths: np.ndarray,
    controller: str,
    seed: int,
    duration: float | None = None,
) -> dict[str, np.ndarray]:
    """Simulate one chunk of variants; returns ``OUTCOME_FIELDS`` -> (B,) arrays.

    Module-level (and taking the scenario as JSON) so that process pools and Ray can ship it. The
    simulated world is prepared once per process and scenario (``sim.prepare``) and reused.
    """
    from deepcrashtest.sim import simulate_batch

    world = _prepared_world(scenario_json, duration)
    res = simulate_batch(world, ego_offsets=offsets, ego_paths=paths, controller=controller, seed=seed)
    return {k: np.asarray(getattr(res, k), dtype=float) for k in OUTCOME_FIELDS}


def simulate_variants(
    scenario_json: str,
    space: SearchSpace,
    theta: np.ndarray,
    controller: str,
    seed: int,
    duration: float | None = None,
) -> dict[str, np.ndarray]:
    """:func:`simulate_chunk` of the variants ``theta`` (B, D) of ``space``: their paths are computed here, in the
    worker (the parent would spend ~0.1 s per 1,000 variants on them, and more shipping them to the workers)."""
    th = np.atleast_2d(np.asarray(theta, dtype=float))
    # the start offset is already in the paths (rotated with the ego's sampled initial heading, so that a
    # variant's Scenario file holds exactly the path simulated here): no extra offset
    return simulate_chunk(scenario_json, np.zeros((len(th), 2)), space.paths(th), controller, seed, duration)


_CACHE: dict[tuple[str, float | None], Any] = {}


def _prepared_world(scenario_json: str, duration: float | None, scenario: Scenario | None = None) -> Any:
    """Parse and prepare each scenario once per process (workers see the same JSON many times); ``scenario``:
    the validated Scenario of that JSON where the caller has it (not parsed again)."""
    from deepcrashtest.sim import prepare

    key = (scenario_json, duration)
    if key not in _CACHE:
        _CACHE.clear()
        sc = scenario if scenario is not None else Scenario.model_validate_json(scenario_json)
        _CACHE[key] = prepare(sc, duration=duration)
    return _CACHE[key]


@dataclass
class Evaluator:
    """Turns parameter vectors into simulated outcomes and counts the simulations run."""

    scenario: Scenario
    space: SearchSpace
    controller: str = "replay"
    seed: int = 0
    engine: str = "local"
    workers: int = 1
    duration: float | None = None  # seconds simulated (None: the whole scenario)
    chunk: int | None = None  # variants per simulator call (None: CHUNK; with the replay controller REPLAY_CHUNK)
    simulations: int = 0
    on_progress: Callable[[int], None] | None = field(default=None, repr=False)  # simulations just run
    in_process_work: int = IN_PROCESS_WORK  # variant-steps below which a call runs here, without the pool
    _json: str = field(default="", repr=False)
    _pool: Any = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.engine not in ENGINES:
            raise UserError(f"--engine must be one of {', '.join(ENGINES)} (got {self.engine!r})")
        if self.chunk is not None and self.chunk < 1:
            raise UserError(f"chunk size must be >= 1 (got {self.chunk})")
        check_workers(self.workers)
        self._json = self.scenario.model_dump_json()

    # ------------------------------------------------------------------ engines
    def __enter__(self) -> Evaluator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop the worker processes. Every result is in by now, so this does not wait for them to exit (each
        frees its share of the batch's arrays meanwhile): the search writes its outputs while they go."""
        if self._pool is not None and self.engine == "local":
            self._pool.shutdown(wait=False)
        self._pool = None

    def _map(self, chunks: Sequence[np.ndarray]) -> list[dict[str, np.ndarray]]:
        args = [(self._json, self.space, th, self.controller, self.seed, self.duration) for th in chunks]
        results: Iterable[dict[str, np.ndarray]]
        if self.engine == "ray":
            results = _ray_map(args, self.workers)
        elif self.workers == 1 or len(chunks) == 1 or self._small(sum(len(th) for th in chunks)):
            results = (simulate_variants(*a) for a in args)
        else:
            if self._pool is None:
                self._pool = ProcessPoolExecutor(max_workers=self.workers)
            results = self._pool.map(simulate_variants, *zip(*args, strict=True))
        parts = []
        for th, part in zip(chunks, results, strict=True):  # as each chunk finishes: the progress bar
            parts.append(part)
            self.simulations += len(th)
            if self.on_progress is not None:
                self.on_progress(len(th))
        return parts

    def _small(self, variants: int) -> bool:
        """Whether ``variants`` variants are too little work to start the worker pool for (``in_process_work``)."""
        return self._pool is None and variants * len(self.world().times) < self.in_process_work

    def warm(self) -> None:
        """Prepare the scenario's world and record the agents' run in this process (local engine, several
        workers), so that the worker processes forked next share them instead of each building its own."""
        if self.engine != "local" or self.workers == 1 or self._pool is not None:
            return
        from deepcrashtest.sim.agents import agent_timeline
        from deepcrashtest.sim.vehicle import VehicleLimits

        agent_timeline(_prepared_world(self._json, self.duration, self.scenario), VehicleLimits()).record_all()

    def world(self) -> Any:
        """The scenario's simulated world as the local workers use it (prepared once per process; the parent's
        after :meth:`warm`, with the agents' recorded run)."""
        return _prepared_world(self._json, self.duration, self.scenario)

    # ------------------------------------------------------------------ evaluate
    def __call__(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        """Simulate the variants ``theta`` (B, D); returns outcome arrays (B,) plus ``change``."""
        th = np.atleast_2d(np.asarray(theta, dtype=float))
        replay = self.controller == "replay"
        n = self.chunk or (REPLAY_CHUNK if replay else CHUNK)
        if replay:  # no sensor noise: any cut gives the same results; balance the workers
            per_worker = -(-len(th) // (self.workers * n))
            n = max(1, -(-len(th) // (self.workers * per_worker)))
        chunks = [th[i : i + n] for i in range(0, len(th), n)]
        parts = self._map(chunks)
        out = {k: np.concatenate([p[k] for p in parts]) for k in OUTCOME_FIELDS}
        out["collided"] = out["collided"].astype(bool)
        out["change"] = self.space.change(th)
        return out


def _ray_map(args: list[tuple[Any, ...]], workers: int) -> list[dict[str, np.ndarray]]:
    """Run ``simulate_chunk`` on Ray (a local instance with ``workers`` CPUs unless one is running)."""
    try:
        import ray
    except ImportError:
        raise UserError("--engine ray needs Ray: pip install 'deepcrashtest[ray]'") from None
    if not ray.is_initialized():
        ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
    remote: Any = ray.remote(simulate_variants)
    ref = ray.put(args[0][0])
    return ray.get([remote.remote(ref, *a[1:]) for a in args])
