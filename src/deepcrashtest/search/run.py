"""``deepcrashtest search``: run the random reference experiment and/or the adaptive search on one scenario."""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from deepcrashtest.errors import UserError, check_seed
from deepcrashtest.fileio import output_set, restage_paths
from deepcrashtest.forking import Helper
from deepcrashtest.scenario import Scenario
from deepcrashtest.search import outputs, plot, table
from deepcrashtest.search.evaluate import Evaluator
from deepcrashtest.search.methods import CemConfig, Log, boundary_scan, cem_search, first_safe, is_safe, random_search
from deepcrashtest.search.space import SearchSpace
from deepcrashtest.ui import progress_bar

METHODS = ("random", "cem", "both")
MAX_VARIANTS = 1_000_000  # simulations of one method (~15 min at 1,000 variants/s; more is a typo, not a search)
MAX_BOX_M = 1_000.0  # metres: a start box side beyond 1 km moves the ego off its road, no perturbation
MAX_NOISE_SIGMA_M = 100.0  # metres: the std of the control-point noise
OUTPUT_FILES = ("results.csv", "summary.json", "starts.png", "safe_variants", "best_vs_original.mp4")
NO_CRASH_NOTE = (
    "the ego does not collide in the original scenario: there is no crash to avoid, so every variant in which "
    "the ego touches nobody counts as safe"
)


@dataclass(frozen=True)
class SearchConfig:
    """Everything that decides a search's result (recorded in summary.json and in each variant's provenance)."""

    starts: int = 32
    noise_variants: int = 4
    box_lateral: float = 4.0  # metres, full width of the start box (+-2 m)
    box_longitudinal: float = 8.0  # metres, full length of the start box (+-4 m)
    noise_sigma: float = 0.3  # metres, std of the control-point noise
    controller: str = "replay"
    method: str = "both"
    seed: int = 0
    margin: float = 0.0  # metres: safe means no collision and robustness > margin
    cem_budget: int | None = None  # simulations for CEM (default: as many as the random experiment)
    boundary_directions: int = 16  # rays of the boundary scan (0: no scan)
    max_scenarios: int = 32  # safe variants written as Scenario files (least change first)
    video: bool = True
    duration: float | None = None  # seconds simulated per variant (None: the whole scenario)

    def check(self) -> None:
        check_seed(self.seed)
        if self.method not in METHODS:
            raise UserError(f"--method must be one of {', '.join(METHODS)} (got {self.method!r})")
        if self.starts < 1 or self.noise_variants < 1:
            raise UserError(f"--starts and --noise-variants must be >= 1 (got {self.starts}, {self.noise_variants})")
        if self.starts * self.noise_variants > MAX_VARIANTS:
            raise UserError(
                f"--starts x --noise-variants must be at most {MAX_VARIANTS:,} variants "
                f"(got {self.starts} x {self.noise_variants})"
            )
        if self.cem_budget is not None and not 1 <= self.cem_budget <= MAX_VARIANTS:
            raise UserError(f"cem_budget must be 1-{MAX_VARIANTS:,} simulations (got {self.cem_budget})")
        if self.boundary_directions < 0 or self.max_scenarios < 0:
            raise UserError("--boundary-directions and --max-scenarios must be >= 0")
        for name, value, top in (
            ("--box-lateral", self.box_lateral, MAX_BOX_M),
            ("--box-longitudinal", self.box_longitudinal, MAX_BOX_M),
            ("--noise-sigma", self.noise_sigma, MAX_NOISE_SIGMA_M),
        ):
            if not (math.isfinite(value) and 0.0 <= value <= top):
                raise UserError(f"{name} must be 0-{top:g} m (got {value})")
        if self.duration is not None and not (math.isfinite(self.duration) and self.duration > 0):
            raise UserError(f"--duration must be a positive number of seconds (got {self.duration})")


def _expected_simulations(cfg: SearchConfig) -> int:
    """About how many variants the search simulates (the progress bar's total)."""
    random = cfg.starts * cfg.noise_variants if cfg.method in ("random", "both") else 0
    cem = (cfg.cem_budget or cfg.starts * cfg.noise_variants) if cfg.method in ("cem", "both") else 0
    return 1 + random + cem


def run_search(
    scenario: Scenario,
    output: str | Path,
    cfg: SearchConfig,
    engine: str = "local",
    workers: int = 1,
    force: bool = False,
    helper: Helper | None = None,
) -> dict[str, Any]:
    """Search variants of ``scenario``, write the outputs under ``output``, return the summary.

    The outputs are one set (:func:`deepcrashtest.fileio.output_set`): all from this run, or none.
    ``helper``: the output helper of :func:`deepcrashtest.search.plot.start_helper` (the command line starts it
    before its imports; by default one is started here): it writes results.csv and starts.png while this
    process writes the rest.
    """
    cfg.check()
    out = Path(output)
    with output_set(out, OUTPUT_FILES, force) as stage, contextlib.ExitStack() as stack:
        if helper is None:
            helper = stack.enter_context(plot.start_helper())
        summary = _search(scenario, stage, cfg, engine, workers, helper)
        summary["outputs"] = restage_paths(summary["outputs"], stage, out)
        outputs.write_summary(summary, stage / "summary.json", False)
    return summary


def _search(
    scenario: Scenario, out_dir: Path, cfg: SearchConfig, engine: str, workers: int, helper: Helper
) -> dict[str, Any]:
    """Run the search and write every output but summary.json into ``out_dir`` (an empty staging folder)."""
    space = SearchSpace.for_scenario(scenario, cfg.box_lateral, cfg.box_longitudinal, cfg.noise_sigma)
    force = False
    t0 = time.perf_counter()
    log = Log()
    cem_best: np.ndarray | None = None
    boundary = None
    with (
        progress_bar("search", _expected_simulations(cfg)) as advance,
        Evaluator(
            scenario,
            space,
            cfg.controller,
            cfg.seed,
            engine,
            workers,
            cfg.duration,
            on_progress=advance,
        ) as ev,
    ):
        original = _original_and_random(ev, log, cfg)
        if cfg.method in ("cem", "both"):
            budget = cfg.cem_budget or cfg.starts * cfg.noise_variants
            cem_cfg = CemConfig(budget=budget, margin=cfg.margin, line_search=min(16, budget // 4))
            cem_best = cem_search(ev, log, np.random.default_rng([cfg.seed, 2]), cem_cfg)
            if cfg.boundary_directions:
                boundary = boundary_scan(ev, log, cfg.boundary_directions, margin=cfg.margin)
        n_sims = ev.simulations
    elapsed = time.perf_counter() - t0
    crash = crash_question(scenario, cfg, ev.world)  # the world the evaluator prepared (kept after it closes)

    theta, res = log.arrays()
    safe = is_safe(res, cfg.margin)
    df = outputs.results_table(space, theta, res, log.method, log.iteration, safe)
    meta = {**asdict(cfg), "engine": engine}
    meta.pop("video")
    # the helper writes these meanwhile; replacing allowed (this run's own staging folder: a job rerun here after
    # the helper died replaces its partial file)
    helper.submit(table.write_csv, df, out_dir / "results.csv", True)
    scen_paths, problems, best_sc = outputs.write_variants(
        scenario, space, df, theta, out_dir / "safe_variants", meta, cfg.max_scenarios, force
    )
    best_id = _best_safe(df, problems)
    is_random = np.array(log.method) == "random"
    helper.submit(
        plot.plot_starts,
        {k: df[k] for k in ("variant", "method", "safe", "d_lat", "d_lon")},
        space.half_box,
        boundary,
        best_id,
        out_dir / "starts.png",
        True,
        f"{scenario.name}: {int(safe[is_random].sum())} of {int(is_random.sum())} random variants safe",
    )
    summary: dict[str, Any] = {
        "scenario": scenario.name,
        "controller": cfg.controller,
        "seed": cfg.seed,
        "engine": engine,
        "workers": workers,
        "original": {"collided": bool(original["collided"][0]), **_metrics(original, 0)},
        "note": None if bool(original["collided"][0]) else NO_CRASH_NOTE,
        "crash": crash,
        "simulations": n_sims,
        "elapsed_s": round(elapsed, 3),
        "variants_per_s": round(n_sims / elapsed, 1) if elapsed > 0 else None,
        "methods": _method_summaries(df, res, log.method, cfg, cem_best, space),
        "boundary": boundary,
        "best_safe": _row(df, best_id),
        "config": meta,
    }
    summary["outputs"] = {
        "results_csv": str(out_dir / "results.csv"),
        "safe_scenarios": scen_paths,
        "scenario_problems": [f"variant {k}: {v}" for k, v in problems.items()],
        "plot": str(helper.results()[-1]),  # the helper's jobs: results.csv, starts.png
        "video": None,
    }
    if cfg.video and best_sc is not None:
        r = summary["best_safe"]
        summary["outputs"]["video"] = outputs.write_video(
            scenario,
            best_sc,
            out_dir / "best_vs_original.mp4",
            cfg.controller,
            cfg.seed,
            force,
            cfg.duration,
            f"variant {r['variant']}: start ({r['d_lon_m']:+.2f}, {r['d_lat_m']:+.2f}) m, change {r['change_m']:.2f} m",
        )
    return summary


def _original_and_random(ev: Evaluator, log: Log, cfg: SearchConfig) -> dict[str, np.ndarray]:
    """Simulate the original (logged first) and the random experiment (``random``/``both``); the original's outcome.

    With the replay controller a variant's outcome does not depend on the batch it is simulated in, so the
    original joins the random experiment's batch: one call, simulated by the workers (the parent prepares the
    world and the agents' run once, before they fork), instead of a one-variant run in the parent first.
    """
    zero = np.zeros((1, ev.space.dim))
    rng = np.random.default_rng([cfg.seed, 1])
    if cfg.method in ("random", "both") and cfg.controller == "replay":
        theta = ev.space.reference_grid(rng, cfg.starts, cfg.noise_variants)
        ev.warm()
        out = ev(np.vstack([zero, theta]))
        original = {k: v[:1] for k, v in out.items()}
        log.add("original", 0, zero, original)
        log.add("random", 0, theta, {k: v[1:] for k, v in out.items()})
        return original
    original = ev(zero)
    log.add("original", 0, zero, original)
    if cfg.method in ("random", "both"):
        random_search(ev, log, rng, cfg.starts, cfg.noise_variants)
    return original


def crash_question(scenario: Scenario, cfg: SearchConfig, world: Callable[[], Any] | None = None) -> dict[str, Any]:
    """What the search asks of this scenario's crash, and whether the replay reproduces it.

    Every variant changes the ego only; the agents replay their trajectories, so a crash between two
    agents (third party) happens in every variant. A variant is safe when the ego touches nobody (and
    stays ``margin`` metres away). For a third-party crash the original is simulated once to check
    that the two agents still crash (``reproduced``, with the simulated time and pair). ``world``: gives the
    search's prepared world (its agents' run recorded): with the replay controller, where the original's ego
    touches nobody, the agents' contacts come from that run (``sim.agent_collisions``: the same contacts,
    without a second run of the whole scenario step by step).
    """
    c = scenario.collision
    out: dict[str, Any] = {
        "kind": "none" if c is None else "ego" if c.involves_ego else "third-party",
        "pair": None if c is None else list(c.participants),
        "observed_time_s": None if c is None else round(c.time_s, 3),
        "safe_means": f"the ego touches no road user (robustness > {cfg.margin} m)",
    }
    if c is not None and not c.involves_ego:
        from deepcrashtest.sim import agent_collisions, simulate

        contacts = agent_collisions(world()) if world is not None and cfg.controller == "replay" else None
        if contacts is None:
            contacts = simulate(scenario, controller=cfg.controller, seed=cfg.seed, duration=cfg.duration).collisions
        hit = next((x for x in contacts if set(x["vehicles"]) == set(c.participants)), None)
        out["reproduced"] = hit is not None
        out["simulated_time_s"] = None if hit is None else hit["time"]
        out["first_contact"] = contacts[0] if contacts else None
    return out


def _best_safe(df: table.Table, problems: dict[int, str]) -> int | None:
    """The safe variant with the least change among those that make a valid Scenario (ties: the lowest id)."""
    ok = df["safe"] & ~np.isin(df["variant"], list(problems))
    if not ok.any():
        return None
    rows = np.flatnonzero(ok)
    return int(df["variant"][rows[np.lexsort((df["variant"][rows], df["change_m"][rows]))[0]]])


def _finite(v: Any) -> float | None:
    f = float(v)
    return round(f, 4) if math.isfinite(f) else None


def _metrics(res: dict[str, np.ndarray], i: int) -> dict[str, Any]:
    keys = ("robustness", "min_distance", "collision_time", "min_ttc", "aeb_time", "delta_v_ego")
    return {k: _finite(res[k][i]) for k in keys}


def _row(df: table.Table, vid: int | None) -> dict[str, Any] | None:
    if vid is None:
        return None
    i = int(np.flatnonzero(df["variant"] == vid)[0])
    return {
        "variant": int(vid),
        "method": str(df["method"][i]),
        "d_lon_m": _finite(df["d_lon"][i]),
        "d_lat_m": _finite(df["d_lat"][i]),
        "change_m": _finite(df["change_m"][i]),
        "robustness": _finite(df["robustness"][i]),
        "min_distance": _finite(df["min_distance"][i]),
    }


def _nan_extreme(v: np.ndarray, largest: bool) -> float:
    """The largest (or smallest) value of ``v`` ignoring NaN; NaN when there is none (pandas' ``max``/``min``)."""
    v = v[~np.isnan(v)]
    return float("nan") if not len(v) else float(v.max() if largest else v.min())


def _method_summaries(
    df: table.Table,
    res: dict[str, np.ndarray],
    methods: list[str],
    cfg: SearchConfig,
    cem_best: Any,
    space: SearchSpace,
) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for m in ("random", "cem", "boundary"):
        rows = df["method"] == m
        if not rows.any():
            continue
        safe = df["safe"] & rows
        out[m] = {
            "simulations": int(rows.sum()),
            "safe": int(safe.sum()),
            "safe_fraction": round(int(safe.sum()) / int(rows.sum()), 4),
            "first_safe_at": first_safe(res, methods, m, cfg.margin),
            "min_change_safe_m": _finite(_nan_extreme(df["change_m"][safe], False)) if safe.any() else None,
            "max_robustness": _finite(_nan_extreme(df["robustness"][rows], True)),
        }
    if "random" in out:
        out["random"]["starts"] = cfg.starts
        out["random"]["noise_variants"] = cfg.noise_variants
        rows = df["method"] == "random"
        start_index = (df["simulation"][rows] - 1) // cfg.noise_variants
        # distinct starts (a set: np.unique imports numpy.ma, ~25 ms of CPU, for one count)
        out["random"]["starts_with_a_safe_variant"] = len(set(start_index[df["safe"][rows]].tolist()))
    if "cem" in out and cem_best is not None:
        out["cem"]["best_change_m"] = _finite(space.change(cem_best)[0])
    return out
