"""``deepcrashtest batch``: extract -> scenario -> search over a folder of videos, resumable.

Inputs are the folder's videos (``*.mp4 *.mov *.avi *.mkv``) and Scenario files (``*.json``, which
skip extraction). Each input gets its own output folder ``OUT/<name>/``. ``OUT/manifest.json``
records every input's status (``pending``, ``running``, ``done``, ``failed``), error and timings;
it is rewritten atomically before and after each input, so killing the batch at any instant
(even ``kill -9``) loses nothing already finished, and ``--resume`` skips the finished inputs and
re-runs the rest. A failing input is recorded as failed and the batch goes on.
"""

from __future__ import annotations

import json
import time
import traceback
from dataclasses import asdict
from pathlib import Path
from typing import Any

from deepcrashtest.errors import UserError
from deepcrashtest.eval.plausibility import plausibility
from deepcrashtest.fileio import atomic_write_text, ensure_output_dir
from deepcrashtest.scenario import Scenario
from deepcrashtest.search.run import SearchConfig, run_search
from deepcrashtest.ui import track

VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv")
SCENARIO_SUFFIX = ".json"
MANIFEST = "manifest.json"
MANIFEST_VERSION = 1


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
) -> dict[str, Any]:
    """Process every input of ``inputs`` into ``output/<name>/``; returns the final manifest summary."""
    cfg = cfg or SearchConfig()
    check_options(cfg, engine, workers)  # every option before the first input
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
    skipped = 0
    for item, name in track(list(zip(items, names, strict=True)), "batch", total=len(items)):
        entry = manifest["items"][name]
        if resume and entry.get("status") == "done":
            skipped += 1
            continue
        entry.update(status="running", output=str(out / name), error=None, started=time.time())
        write_manifest(mpath, manifest)
        t0 = time.perf_counter()
        try:
            # an unfinished earlier attempt may have left files in this input's own folder: replace them
            result = process_video(item, out / name, cfg, engine, workers, force=True)
        except Exception as exc:  # a bad input must not stop the batch
            entry.update(status="failed", error=_named_error(exc, item), result=None)
            if not isinstance(exc, UserError):
                entry["traceback"] = traceback.format_exc(limit=4)
        else:
            entry.update(status="done", result=result)
        entry["seconds"] = round(time.perf_counter() - t0, 2)
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


def _named_error(exc: Exception, item: Path) -> str:
    """The manifest's error of a failed input: the error's kind and text, led by the input's path where the
    text does not name it (a 1-frame video's "fewer than 2 frames" named no file)."""
    text = str(exc) if str(item) in str(exc) else f"{item}: {exc}"
    return f"{type(exc).__name__}: {text}"


def check_options(cfg: SearchConfig, engine: str, workers: int) -> None:
    """Refuse bad search options (method, counts, seed, engine, workers, controller) as one UserError."""
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
