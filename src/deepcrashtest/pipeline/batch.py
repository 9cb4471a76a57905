"""``deepcrashtest batch``: extract -> scenario -> search over a folder of videos, resumable.

Inputs are the folder's videos (``*.mp4 *.mov *.avi *.mkv``) and Scenario files (``*.json``, which
skip extraction). Each input gets its own output folder ``OUT/<name>/``. ``OUT/manifest.json``
records every input's status (``pending``, ``running``, ``done``, ``failed``), error and timings;
it is rewritten atomically before and after each input, so killing the batch at any instant
(even ``kill -9``) loses nothing already finished, and ``--resume`` skips the finished inputs and
re-runs the rest. A failing input is recorded as failed and the batch goes on.
"""

from __future__ import annotations

import contextlib
import json
import os
import time
import traceback
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from dataclasses import asdict
from pathlib import Path
from typing import Any

from deepcrashtest.errors import UserError
from deepcrashtest.eval.plausibility import plausibility
from deepcrashtest.fileio import atomic_write_text, ensure_output_dir
from deepcrashtest.forking import usable_cores
from deepcrashtest.scenario import Scenario
from deepcrashtest.search.run import SearchConfig, run_search
from deepcrashtest.ui import track
from deepcrashtest.video.source import VIDEO_SUFFIXES

SCENARIO_SUFFIX = ".json"
MANIFEST = "manifest.json"
MANIFEST_VERSION = 1
#: At most this many inputs at once (``--jobs``).
MAX_JOBS = 64
#: ``--jobs`` by default: the cores, at most this many, and no more than the free memory holds at JOB_MEMORY_GB each.
DEFAULT_MAX_JOBS = 4
#: Memory (GB) one input's process may need: an extraction of a 1280-px video peaks at ~0.6 GB, of a 4K one
#: (scaled to 1280 px) at ~0.7 GB, with the search's processes beside it.
JOB_MEMORY_GB = 1.5


def default_jobs() -> int:
    """``batch --jobs`` unless given: the cores this process may use (at most :data:`DEFAULT_MAX_JOBS`), no more
    than the free memory holds at :data:`JOB_MEMORY_GB` each (``MemAvailable`` of ``/proc/meminfo``, where there
    is one), at least 1."""
    fit = DEFAULT_MAX_JOBS
    with contextlib.suppress(OSError, ValueError, StopIteration):
        lines = Path("/proc/meminfo").read_text().splitlines()
        kb = next(int(line.split()[1]) for line in lines if line.startswith("MemAvailable:"))
        fit = int(kb / 1024**2 // JOB_MEMORY_GB)
    return max(1, min(usable_cores(), DEFAULT_MAX_JOBS, fit))


def list_inputs(folder: str | Path) -> list[Path]:
    """Videos and Scenario files directly in ``folder``, sorted by name."""
    d = Path(folder)
    if not d.is_dir():
        raise UserError(f"{d}: input folder not found")
    items = sorted(p for p in d.iterdir() if p.is_file() and p.suffix.lower() in (*VIDEO_SUFFIXES, SCENARIO_SUFFIX))
    if not items:
        raise UserError(f"{d}: no videos ({' '.join(VIDEO_SUFFIXES)}) or scenario files (*.json) in this folder")
    return items


def process_video(
    video: str | Path,
    outdir: str | Path,
    cfg: SearchConfig | None = None,
    engine: str = "local",
    workers: int = 1,
    force: bool = False,
) -> dict[str, Any]:
    """One input end to end: extract (videos only) -> Scenario -> search. Returns a short summary (with the
    scenario's crash and whether its vehicles move as vehicles can, :mod:`deepcrashtest.eval.plausibility`: what
    to look at first among thousands of clips).

    Videos go through ``deepcrashtest.pipeline.extract.extract_video(video, outdir / "extract", ...)``;
    ``*.json`` inputs are Scenario files and go straight to the search.
    """
    src = Path(video)
    out = Path(outdir)  # made by the first output set (extract or search); absent when the input fails early
    cfg = cfg or SearchConfig()
    if src.suffix.lower() == SCENARIO_SUFFIX:
        scenario = Scenario.load(src)
    else:
        scenario = _extract(src, out / "extract", cfg.seed, force)
    summary = run_search(scenario, out / "search", cfg, engine=engine, workers=workers, force=force)
    methods = summary["methods"]
    col = scenario.collision
    plaus = plausibility(scenario)
    return {
        "scenario": scenario.name,
        "crash": None
        if col is None
        else {"participants": list(col.participants), "time_s": col.time_s, "source": col.source},
        "plausibility": {
            k: plaus[k]
            for k in (
                "vehicles_with_half_turns",
                "over_turning_share",
                "over_traction_share",
                "sliding_share",
                "overlapping_pairs",
            )  # fmt: skip
        },
        "original_collided": summary["original"]["collided"],
        "simulations": summary["simulations"],
        "safe_random": methods.get("random", {}).get("safe"),
        "first_safe_random": methods.get("random", {}).get("first_safe_at"),
        "first_safe_cem": methods.get("cem", {}).get("first_safe_at"),
        "best_change_m": (summary["best_safe"] or {}).get("change_m"),
    }


def _extract(video: Path, outdir: Path, seed: int, force: bool) -> Scenario:
    from deepcrashtest.pipeline.extract import extract_video

    res = extract_video(video, outdir, seed=seed, force=force)
    if res.get("shots"):
        made = [r["scenario"] for r in res["shots"] if r.get("scenario")]
        raise UserError(
            f"{video}: a compilation (cuts at {res['cuts_s']} s); one scenario per shot was written "
            f"({', '.join(made) or 'none usable'}): search each of them"
        )
    return Scenario.load(Path(res.get("scenario") or outdir / "scenario.json"))


# --------------------------------------------------------------------------- manifest
def read_manifest(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise UserError(f"{path}: unreadable manifest ({exc}); remove it or use --force") from None
    if not isinstance(data, dict) or data.get("version") != MANIFEST_VERSION or "items" not in data:
        raise UserError(f"{path}: not a deepcrashtest batch manifest")
    return data


def write_manifest(path: Path, manifest: dict[str, Any]) -> None:
    manifest["updated"] = time.strftime("%Y-%m-%dT%H:%M:%S")
    atomic_write_text(path, json.dumps(manifest, indent=1) + "\n", force=True)


def run_batch(
    inputs: str | Path,
    output: str | Path,
    cfg: SearchConfig | None = None,
    engine: str = "local",
    workers: int = 1,
    resume: bool = False,
    force: bool = False,
    jobs: int = 1,
) -> dict[str, Any]:
    """Process every input of ``inputs`` into ``output/<name>/``; returns the final manifest summary.

    ``jobs``: inputs processed at once, each in its own process (:func:`_outcomes`); ``workers``: the search's
    processes, shared among the jobs. The outputs are the same whatever ``jobs`` is."""
    cfg = cfg or SearchConfig()
    check_options(cfg, engine, workers, jobs)  # every option before the first input
    items = list_inputs(inputs)
    out = ensure_output_dir(output)
    mpath = out / MANIFEST
    if mpath.exists() and not (resume or force):
        raise UserError(f"{mpath}: already exists (use --resume to continue or --force to start again)")
    manifest = read_manifest(mpath) if (mpath.exists() and resume) else None
    if manifest is None:
        manifest = {"version": MANIFEST_VERSION, "inputs": str(Path(inputs)), "config": asdict(cfg), "items": {}}
    names = _unique_names(items)
    if not (resume or force):
        taken = [n for n in names if (out / n).exists()]
        if taken:
            raise UserError(f"{out / taken[0]}: already exists (use --resume to continue or --force to start again)")
    for item, name in zip(items, names, strict=True):
        manifest["items"].setdefault(name, {"input": str(item), "status": "pending"})
    write_manifest(mpath, manifest)
    todo = [(item, name) for item, name in zip(items, names, strict=True)]
    if resume:
        todo = [(item, name) for item, name in todo if manifest["items"][name].get("status") != "done"]
    skipped = len(items) - len(todo)

    def started(name: str) -> None:
        entry = manifest["items"][name]
        entry.pop("traceback", None)  # an earlier attempt's
        entry.update(status="running", output=str(out / name), error=None, started=time.time())
        write_manifest(mpath, manifest)

    outcomes = _outcomes(todo, out, cfg, engine, workers, jobs, started)
    for name, outcome in track(outcomes, "batch", total=len(todo)):
        manifest["items"][name].update(outcome)
        write_manifest(mpath, manifest)
    counts = {s: sum(1 for e in manifest["items"].values() if e["status"] == s) for s in ("done", "failed")}
    return {
        "manifest": str(mpath),
        "inputs": len(items),
        "done": counts["done"],
        "failed": counts["failed"],
        "skipped": skipped,
        "errors": {n: e["error"] for n, e in manifest["items"].items() if e["status"] == "failed"},
    }


def _outcomes(
    todo: list[tuple[Path, str]],
    out: Path,
    cfg: SearchConfig,
    engine: str,
    workers: int,
    jobs: int,
    started: Callable[[str], None],
) -> Iterator[tuple[str, dict[str, Any]]]:
    """(name, manifest fields) of each input as it finishes: one after the other in this process, or with ``jobs``
    > 1 up to ``jobs`` at once in processes of their own (``spawn``; the search's ``workers`` shared among them).
    ``started(name)`` is called as an input is taken up.

    An extraction keeps ~1.4 of 2 cores busy (its serial parts: start-up, stage 2, the report), so two inputs at
    once finish sooner (6 crash clips on 2 cores: 38.5 s one at a time, 27.4 s two at a time). A job's process dies
    with the batch (``kill -9`` too: it must not go on writing an input that ``--resume`` takes up again)."""
    if jobs <= 1 or len(todo) <= 1 or not _spawn_can_start():
        for item, name in todo:
            started(name)
            yield name, attempt(item, out / name, cfg, engine, workers)
        return
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    def new_pool() -> ProcessPoolExecutor:
        return ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn"), initializer=_job_process)

    share = max(1, workers // jobs)
    queue = list(reversed(todo))
    running: dict[Future[dict[str, Any]], tuple[Path, str]] = {}
    pool = new_pool()
    try:
        while queue or running:
            while queue and len(running) < jobs:
                item, name = queue.pop()
                started(name)
                running[pool.submit(attempt, item, out / name, cfg, engine, share)] = (item, name)
            finished, _ = wait(running, return_when=FIRST_COMPLETED)
            if any(isinstance(fut.exception(), BrokenProcessPool) for fut in finished):
                # a job's process died (out of memory, killed), and its pool with it: every input in it failed
                pool.shutdown(wait=False, cancel_futures=True)
                pool, finished = new_pool(), set(running)
            for fut in finished:
                item, name = running.pop(fut)
                yield name, _outcome(fut, item)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _spawn_can_start() -> bool:
    """Whether a job's process can start here: ``spawn`` runs the caller's main script again in it, which a program
    read from standard input (``python -``, ``python < file``) does not have (a ``-c`` program or a notebook has no
    script, which is fine); the inputs are then taken one at a time."""
    import sys

    path = getattr(sys.modules.get("__main__"), "__file__", None)
    return path is None or Path(path).is_file()


def _outcome(fut: Future[dict[str, Any]], item: Path) -> dict[str, Any]:
    """The manifest fields of a job's finished (or broken) future."""
    from concurrent.futures.process import BrokenProcessPool

    exc = fut.exception() if fut.done() else None
    if exc is None and fut.done():
        return fut.result()
    if exc is None or isinstance(exc, BrokenProcessPool):
        error = f"{item}: a process of the batch died while this input was in it (out of memory, or killed)"
    else:
        error = _named_error(exc, item)
    return {"status": "failed", "result": None, "error": error}


def attempt(item: Path, outdir: Path, cfg: SearchConfig, engine: str, workers: int) -> dict[str, Any]:
    """One input of a batch (:func:`process_video`) -> its manifest fields: ``status`` done or failed, ``result``,
    ``error`` (and ``traceback`` for an internal error), ``seconds``. An unfinished earlier attempt may have left
    files in the input's own folder: they are replaced."""
    t0 = time.perf_counter()
    outcome: dict[str, Any]
    try:
        outcome = {"status": "done", "result": process_video(item, outdir, cfg, engine, workers, force=True)}
    except Exception as exc:  # a bad input must not stop the batch
        outcome = {"status": "failed", "error": _named_error(exc, item), "result": None}
        if not isinstance(exc, UserError):
            outcome["traceback"] = traceback.format_exc(limit=4)
    outcome["seconds"] = round(time.perf_counter() - t0, 2)
    return outcome


def _job_process() -> None:
    """A job's process: no progress bars of its own (the batch's shows the inputs), and ended as soon as the batch's
    process dies (``kill -9`` too), however far its input got: a watch on the parent's sentinel, and Linux's
    ``PR_SET_PDEATHSIG`` where it is."""
    import ctypes
    import multiprocessing
    import signal
    import sys
    import threading

    from deepcrashtest.ui import set_quiet

    set_quiet(True)
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # 1: PR_SET_PDEATHSIG
    parent = multiprocessing.parent_process()
    if parent is not None:  # also a parent that died while this process was starting
        threading.Thread(target=_end_with, args=(parent.sentinel,), name="batch-watch", daemon=True).start()


def _end_with(sentinel: int) -> None:
    """Wait for the batch's process to end (its sentinel becomes ready), then end this one at once."""
    from multiprocessing.connection import wait

    wait([sentinel])
    os._exit(1)


def _named_error(exc: BaseException, item: Path) -> str:
    """The manifest's error of a failed input: the error's kind and text, led by the input's path where the
    text does not name it (a 1-frame video's "fewer than 2 frames" named no file)."""
    text = str(exc) if str(item) in str(exc) else f"{item}: {exc}"
    return f"{type(exc).__name__}: {text}"


def check_options(cfg: SearchConfig, engine: str, workers: int, jobs: int = 1) -> None:
    """Refuse bad search options (method, counts, seed, engine, workers, controller) and jobs as one UserError."""
    if not 1 <= jobs <= MAX_JOBS:
        raise UserError(f"--jobs must be 1-{MAX_JOBS} (got {jobs})")
    if jobs > 1 and engine != "local":
        raise UserError(f"--jobs {jobs} needs --engine local (a Ray cluster spreads each search itself)")
    from deepcrashtest.search.evaluate import ENGINES, check_workers
    from deepcrashtest.sim.controllers import resolve_controller

    cfg.check()
    if engine not in ENGINES:
        raise UserError(f"--engine must be one of {', '.join(ENGINES)} (got {engine!r})")
    check_workers(workers)
    resolve_controller(cfg.controller)


def _unique_names(items: list[Path]) -> list[str]:
    """Output folder names: the file stem, with the suffix added where two inputs share a stem."""
    stems = [p.stem for p in items]
    return [p.stem if stems.count(p.stem) == 1 else p.name.replace(".", "_") for p in items]
