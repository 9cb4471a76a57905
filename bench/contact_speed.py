"""Speed of stage 2's crash correction (``trajectory/contact.py``): this tree against a git reference.

Per clip: stage 2 is rerun from ``<work>/<clip>/scenario_raw.json`` and every ``make_contact`` /
``nudge_apart`` call it makes is recorded (its inputs); each recorded problem is then solved by the
reference solver (``contact.py`` as in ``--ref``, default ``main``, loaded from git) and by this
tree's, one after the other in the same process, and the CPU seconds and the results are compared:
satisfied or not, the correction's size (max, m), and for a crash correction the corrected pair's
first contact time against the crash time (s). Stage 2's output is also compared with the stored
processed scenario ``<work>/<clip>/scenario.json`` (made by the reference): the crash record of
provenance and the largest difference of any vehicle's position (m). Nothing is written.

Usage::

    python bench/contact_speed.py [--work /tmp/deepcrashtest_fidelity] [--clips a,b] [--ref main] [--no-ref] [--json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
import types
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

import deepcrashtest.trajectory.contact as new  # noqa: E402
from deepcrashtest.scenario import Scenario  # noqa: E402
from deepcrashtest.trajectory import crash as crash_phase  # noqa: E402
from deepcrashtest.trajectory.collision import first_contact  # noqa: E402
from deepcrashtest.trajectory.pipeline import process_scenario  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CONTACT = "src/deepcrashtest/trajectory/contact.py"


def reference(ref: str) -> types.ModuleType:
    """``contact.py`` as in git revision ``ref``, as a module of its own."""
    src = subprocess.run(
        ["git", "-C", str(ROOT), "show", f"{ref}:{CONTACT}"], capture_output=True, text=True, check=True
    )
    mod = types.ModuleType("contact_ref")
    sys.modules[mod.__name__] = mod  # dataclasses look their module up
    exec(compile(src.stdout, f"{ref}:{CONTACT}", "exec"), mod.__dict__)
    return mod


def record_problems(raw: Scenario) -> tuple[Scenario, list[tuple[str, tuple[Any, ...]]]]:
    """Run stage 2 on ``raw``: the processed scenario and the correction problems it solved (name, args)."""
    calls: list[tuple[str, tuple[Any, ...]]] = []
    originals = {n: getattr(crash_phase, n) for n in ("make_contact", "nudge_apart")}

    def wrap(name: str) -> Any:
        def f(*args: Any) -> Any:
            calls.append((name, args))
            return originals[name](*args)

        return f

    try:
        for n in originals:
            setattr(crash_phase, n, wrap(n))
        out = process_scenario(raw)
    finally:
        for n, f in originals.items():
            setattr(crash_phase, n, f)
    return out, calls


def compare_stored(sc: Scenario, path: Path) -> dict[str, Any]:
    """Stage 2's output against the stored processed scenario: same crash record, largest position
    difference (m) over the vehicles both have, vehicles only one has."""
    if not path.is_file():
        return {}
    old = Scenario.load(path)
    mine = {v.id: v.trajectory.arrays() for v in sc.vehicles()}
    theirs = {v.id: v.trajectory.arrays() for v in old.vehicles()}
    worst = 0.0
    for k in set(mine) & set(theirs):
        a, b = mine[k], theirs[k]
        t = a["t"][(a["t"] >= b["t"][0]) & (a["t"] <= b["t"][-1])]
        for c in ("x", "y"):
            if len(t):
                worst = max(worst, float(np.abs(np.interp(t, a["t"], a[c]) - np.interp(t, b["t"], b[c])).max()))
    rec = sc.provenance.parameters.get("crash")
    rec_old = old.provenance.parameters.get("crash")
    return {
        "max_pos_diff_m": worst,
        "vehicles_differ": sorted(set(mine) ^ set(theirs)),
        "record_same": rec == rec_old,
        "record": rec,
        "record_stored": rec_old,
    }


def solve(mod: types.ModuleType, name: str, args: tuple[Any, ...]) -> dict[str, Any]:
    """Solve one recorded problem with module ``mod``: CPU seconds and the outcome."""
    spend, spent = mod._Budget.spend, [0]

    def count(self: Any) -> None:
        spent[0] += 1
        spend(self)

    mod._Budget.spend = count  # box-track evaluations, as counted against MAX_EVALS
    try:
        t0 = time.process_time()
        corr = getattr(mod, name)(*args)
        cpu = time.process_time() - t0
    finally:
        mod._Budget.spend = spend
    out: dict[str, Any] = {"cpu_s": cpu, "evals": spent[0], "ok": corr.ok, "max_m": corr.max_m}
    out["window_s"], out["kinematic"] = corr.window_s, corr.kinematic
    if name == "make_contact":
        a, b, t_crash = args[:3]
        tracks = [
            mod.box_track(m, m.xy + d) if len(d) else mod.box_track(m) for m, d in zip((a, b), corr.deltas, strict=True)
        ]
        hit = first_contact(*tracks)
        out["contact_dt_s"] = None if hit is None else hit.time_s - t_crash
    return out


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:+.3f}" if abs(v) < 1 else f"{v:.2f}"
    return str(v)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/deepcrashtest_fidelity"), help="Clips' extraction outputs.")
    ap.add_argument("--clips", default=None, help="Comma-separated clip names (default: every clip in --work).")
    ap.add_argument("--ref", default="main", help="Git revision of the reference contact.py.")
    ap.add_argument("--no-ref", action="store_true", help="Time this tree's solver only.")
    ap.add_argument("--json", action="store_true", help="Print one JSON object instead of the table.")
    args = ap.parse_args()
    names = (
        args.clips.split(",") if args.clips else sorted(p.parent.name for p in args.work.glob("*/scenario_raw.json"))
    )
    ref = None if args.no_ref else reference(args.ref)
    rows: list[dict[str, Any]] = []
    summary: list[dict[str, Any]] = []
    for name in names:
        raw = Scenario.load(args.work / name / "scenario_raw.json")
        t0 = time.process_time()
        processed, problems = record_problems(raw)
        stage2 = time.process_time() - t0
        stored = compare_stored(processed, args.work / name / "scenario.json")
        summary.append({"clip": name, "stage2_cpu_s": stage2, "problems": len(problems), **stored})
        if not args.json:
            print(json.dumps(summary[-1]), file=sys.stderr)
        for k, (fn, fargs) in enumerate(problems):
            row = {"clip": name, "call": f"{fn}#{k}", "stage2_cpu_s": stage2, "new": solve(new, fn, fargs)}
            if ref is not None:
                row["ref"] = solve(ref, fn, fargs)
            rows.append(row)
            if not args.json:
                print(json.dumps(row), file=sys.stderr)
        if not problems:
            rows.append({"clip": name, "call": "-", "stage2_cpu_s": stage2})
    if args.json:
        print(json.dumps({"clips": summary, "rows": rows}, indent=1))
        return
    print("| clip | stage 2 CPU s | problems | crash record as stored | largest position difference m |")
    print("|---|---|---|---|---|")
    for c in summary:
        diff = c.get("max_pos_diff_m")
        cells = [c["clip"], f"{c['stage2_cpu_s']:.2f}", str(c["problems"]), _fmt(c.get("record_same"))]
        print("| " + " | ".join([*cells, "-" if diff is None else f"{diff:.3f}"]) + " |")
    print()
    print(
        "| clip | call | stage 2 s (this tree) | ref s | new s | ref/new | ok ref/new | max m ref/new | dt s ref/new |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        n, f = r.get("new", {}), r.get("ref", {})
        ratio = f["cpu_s"] / max(n["cpu_s"], 1e-9) if f and n else None
        cells = [r["clip"], r["call"], f"{r['stage2_cpu_s']:.2f}", _fmt(f.get("cpu_s")), _fmt(n.get("cpu_s"))]
        cells += ["-" if ratio is None else f"{ratio:.1f}"]
        cells += [f"{_fmt(f.get('ok'))}/{_fmt(n.get('ok'))}", f"{_fmt(f.get('max_m'))}/{_fmt(n.get('max_m'))}"]
        cells += [f"{_fmt(f.get('contact_dt_s'))}/{_fmt(n.get('contact_dt_s'))}"]
        print("| " + " | ".join(cells) + " |")
    solved = [r for r in rows if "new" in r]
    tot_new = sum(r["new"]["cpu_s"] for r in solved)
    if ref is not None and solved:
        tot_ref = sum(r["ref"]["cpu_s"] for r in solved)
        same = sum(r["ref"]["ok"] == r["new"]["ok"] for r in solved)
        dmax = max(abs(r["ref"]["max_m"] - r["new"]["max_m"]) for r in solved)
        med = np.median([r["ref"]["cpu_s"] / max(r["new"]["cpu_s"], 1e-9) for r in solved])
        print(
            f"\n{len(solved)} problems: reference {tot_ref:.1f} s CPU, this tree {tot_new:.1f} s "
            f"(x{tot_ref / max(tot_new, 1e-9):.1f}); same ok {same}/{len(solved)}; largest |max_m| difference "
            f"{dmax:.3f} m; per-call ratio median {med:.1f}"
        )
    else:
        print(f"\n{len(solved)} problems: this tree {tot_new:.1f} s CPU")
    if solved:
        print(f"largest box-track evaluations of one call (MAX_EVALS): {max(r['new']['evals'] for r in solved)}")


if __name__ == "__main__":
    main()
