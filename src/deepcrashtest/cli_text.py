"""The command line's human-readable summaries (:mod:`deepcrashtest.cli` prints them on stdout without ``--json``):
one function per command's result dictionary, plain text or a rich table; no computation beyond formatting."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer


def extract_summary(r: dict[str, Any]) -> None:
    if "shots" in r:  # a compilation: one extraction per shot
        typer.echo(f"{len(r['shots'])} shot(s) extracted; cuts at {r['cuts_s']} s")
        for shot in r["shots"]:
            typer.echo(f"--- {shot['shot']}: frames {shot['first_frame']}-{shot['last_frame']} -> {shot['output']}")
            extract_summary({**shot, "warnings": []})
        for w in r["warnings"]:
            typer.echo(f"warning: {w}")
        return
    rates = r.get("fps_video_range")
    rate = f"variable {rates[0]:.1f}-{rates[1]:.1f} fps, mean {r['fps_video']}" if rates else f"{r['fps_video']} fps"
    typer.echo(
        f"{r['frames']} frames ({r['width']}x{r['height']} @ {rate}), {r['tracks']} tracks, "
        f"mean track length {r['mean_track_length_frames']} frames, {r['fps_achieved']} fps achieved"
    )
    typer.echo(f"wrote {r['tracks_csv']}" + (f" and {r['annotated_mp4']}" if r["annotated_mp4"] else ""))
    if r.get("scenario_raw"):
        cam = r["camera"]
        typer.echo(
            f"ego: {r['ego_distance_m']} m at {r['ego_mean_speed_mps']} m/s mean; {r['agents']} agents; camera "
            f"fx {cam['fx']} px, pitch {cam['pitch_rad']} rad ({cam['pitch_source']}), height {cam['height_m']} m"
        )
    for key in ("scenario_raw", "scenario", "report"):
        if r.get(key):
            typer.echo(f"wrote {r[key]}")
    if r.get("classes"):
        typer.echo("classes: " + ", ".join(f"{k} {v}" for k, v in r["classes"].items()))
    det = r.get("crash_detection")
    if det is not None:
        typer.echo(
            f"crash ({det['source']}): frame {det['frame']}, {' and '.join(str(v) for v in det['pair'])}, "
            f"confidence {det['confidence']}"
            if det.get("found")
            else "crash: none found in the video (stage 2 keeps every road user apart; give one with --crash)"
        )
    if r.get("collision"):
        c = r["collision"]
        pair = " with ".join("ego" if v == 0 else f"road user {v}" for v in (c.get("other_id", 0), c["agent_id"]))
        typer.echo(f"collision: {pair} at t = {c['time_s']:.2f} s")
    for w in r["warnings"]:
        typer.echo(f"warning: {w}")


def sim_summary(r: dict[str, Any]) -> None:
    m = r["metrics"]
    typer.echo(f"{r['scenario']}: {r['vehicles']} vehicles, {r['duration_s']} s, controller {r['controller']}")
    if m["collided"]:
        typer.echo(
            f"collision at {m['collision_time']:.2f} s with vehicle {m['collision_vehicle']}: relative speed "
            f"{m['relative_speed']:.1f} m/s, ego delta-v {_fmt(m['delta_v_ego'])} m/s"
        )
    else:
        typer.echo("no collision of the ego")
    for c in r["collisions"]:
        if 0 not in c["vehicles"]:  # a third-party crash, between two agents
            a, b = c["vehicles"]
            typer.echo(f"contact of road users {a} and {b} at {c['time']:.2f} s: {_fmt(c['relative_speed'])} m/s")
    typer.echo(f"min distance {_fmt(m['min_distance'])} m, min TTC {_fmt(m['min_ttc'])} s, AEB {_fmt(m['aeb_time'])} s")
    rms = r["replay_rms_m"]
    typer.echo(f"replay RMS error: ego {_fmt(rms['ego'])} m, agents {_fmt(rms['agents'])} m")
    if "video" in r:
        typer.echo(f"video: {r['video']}")


def _fmt(v: float | None) -> str:
    return "-" if v is None else f"{v:.2f}"


def search_summary(s: dict[str, Any]) -> None:
    o = s["original"]
    typer.echo(
        f"scenario {s['scenario']} (controller {s['controller']}, seed {s['seed']}): original "
        f"{'collides' if o['collided'] else 'does not collide'} (robustness {o['robustness']} m)"
    )
    if s.get("note"):
        typer.echo(f"  note: {s['note']}")
    c = s.get("crash") or {}
    if c.get("kind") == "third-party":
        seen = f"reproduced at {c['simulated_time_s']} s" if c["reproduced"] else "NOT reproduced by the replay"
        typer.echo(
            f"  third-party crash of road users {c['pair'][0]} and {c['pair'][1]} at {c['observed_time_s']} s "
            f"(replayed in every variant; {seen}); a variant is safe when {c['safe_means']}"
        )
    for name, m in s["methods"].items():
        if not o["collided"]:
            typer.echo(f"  {name:8s} {m['simulations'] - m['safe']:4d} of {m['simulations']:4d} variants collide")
            continue
        if m["first_safe_at"] is None:
            found = "no safe variant found"
        else:
            found = f"first safe after {m['first_safe_at']} simulations; least change {m['min_change_safe_m']} m"
        typer.echo(f"  {name:8s} {m['safe']:4d} of {m['simulations']:4d} safe; {found}")
    b = s["best_safe"]
    if b and o["collided"]:
        typer.echo(
            f"  best safe: variant {b['variant']} ({b['method']}), start ({b['d_lon_m']}, {b['d_lat_m']}) m, "
            f"change {b['change_m']} m, robustness {b['robustness']} m"
        )
    typer.echo(
        f"  {s['simulations']} simulations in {s['elapsed_s']} s ({s['variants_per_s']} variants/s, "
        f"{s['engine']} x{s['workers']})"
    )
    typer.echo(f"  outputs: {Path(s['outputs']['results_csv']).parent}")


def kitti_table(result: dict[str, Any]) -> None:
    from rich.console import Console
    from rich.table import Table

    from deepcrashtest.eval.kitti import TABLE_COLUMNS

    what = f"{result.get('class', 'car')}s"  # cars, pedestrians, cyclists
    table = Table(title=f"KITTI tracking ({what}), world frame: {result['hypotheses']}; match: {result['match_rule']}")
    for c in ["seq", *TABLE_COLUMNS, "HOTA", "IDSW"]:
        table.add_column(c, justify="right")
    for name, row in result["sequences"].items():
        table.add_row(name, *(_cell(row[c]) for c in [*TABLE_COLUMNS, "HOTA", "IDSW"]))
    for name, row in result["paper"].items():
        table.add_row(f"paper {name}", *(_cell(row[c]) for c in TABLE_COLUMNS), "-", "-", style="dim")
    console = Console(width=200)
    console.print(table)
    errors = {n: r["position_error"] for n, r in result["sequences"].items() if "position_error" in r}
    if errors:
        err = Table(title=f"ground-position error of matched {what}, median / p90 m (median % of range)")
        bins = list(next(iter(errors.values())))
        for c in ["seq", *bins]:
            err.add_column(c, justify="right")
        for name, row in errors.items():
            err.add_row(name, *(_err_cell(row[b]) for b in bins))
        console.print(err)
    for name, row in result["sequences"].items():
        h = row.get("heading_error")
        if h and h["n"]:
            console.print(
                f"{name}: heading of matched {what} (modulo a half turn) median {h['median_deg']:.1f} deg, p90 "
                f"{h['p90_deg']:.1f} deg, {100 * h['share_over_20_deg']:.0f} % over 20 deg, "
                f"{100 * h['share_reversed']:.0f} % facing the other way round"
            )
    for note in result.get("notes", []):
        console.print(f"note: {note}", style="dim")


def _err_cell(cell: dict[str, Any]) -> str:
    if not cell["n"]:
        return "-"
    return f"{cell['median_m']:.2f} / {cell['p90_m']:.2f} ({cell['median_pct']:.1f} %)"


def _cell(v: Any) -> str:
    return f"{v:.2f}" if isinstance(v, float) else str(v)


def fidelity_summary(r: dict[str, Any]) -> None:
    from deepcrashtest.eval.plausibility import SLIDE_MAX_DEG

    rep, crash = r["reprojection"], r["crash"]
    typer.echo(f"{r['scenario']}: {rep['tracked_boxes']} tracked boxes of {rep['tracks_in_scenario']} agents")
    for src in ("processed", "simulated"):
        s = rep[src]
        typer.echo(
            f"  {src:9s}: mean IoU {_fmt(s['mean_iou'])}, IoU>=0.5 {_fmt(s['share_iou_ge_0_5'])}, "
            f"median centre error {_fmt(s['median_centre_px'])} px (right {_fmt(s['median_du_px'])}, down "
            f"{_fmt(s['median_dv_px'])}), size ratio w {_fmt(s['median_width_ratio'])} h "
            f"{_fmt(s['median_height_ratio'])}, coverage {_fmt(s['coverage'])}"
        )
    first = crash["first_contact"]
    typer.echo(
        "  first contact: none"
        if first is None
        else f"  first contact: {first['participants']} at video {first['video_time_s']:.2f} s "
        f"({_fmt(first['relative_speed_mps'])} m/s)"
    )
    if crash.get("label") is not None:
        typer.echo(
            f"  label: {crash['label']['description']} -> reproduced {crash['reproduced']}, same pair "
            f"{crash['same_pair']}, dt {_fmt(crash['dt_s'])} s, contacts before {crash['contacts_before_crash']}"
        )
    else:
        typer.echo(f"  video has a crash: {crash['video_has_crash']} ({crash['video_has_crash_source']})")
    p = r.get("plausibility") or {}
    if p.get("vehicles"):
        typer.echo(
            f"  vehicles as vehicles move ({p['vehicles']}): turned half round {p['half_turns']} times, beyond the "
            f"steering limit {p['over_turning']} of {p['steps']} steps, beyond its traction {p['over_traction']}, "
            f"sliding > {SLIDE_MAX_DEG:g} deg "
            f"{p['sliding']} of {p['moving']} moving samples"
        )
    if p.get("overlapping_pairs"):
        pairs = ", ".join(f"{a} and {b} ({s:g} s)" for a, b, s in p["overlapping_pairs"])
        typer.echo(f"  road users passing through each other before the crash: {pairs}")
    typer.echo(f"  time mapping: {r['time_mapping']['rule']}, offset {r['time_mapping']['time_offset_s']:.3f} s")
    for note in r["notes"]:
        typer.echo(f"  note: {note}")
    for name, path in r["outputs"].items():
        typer.echo(f"  {name}: {path}")


def demo_summary(r: dict[str, Any]) -> None:
    typer.echo(f"demo on {r['video']} -> {r['output']}")
    for step in r["steps"]:
        details = ", ".join(
            f"{k}={v}" for k, v in step.items() if k != "step" and isinstance(v, str | int | float | bool) and v != ""
        )
        typer.echo(f"- {step['step']}: {details}")
        for run in step.get("runs", []):  # e.g. the simulator's runs: one line each
            typer.echo(
                f"    {run.get('scenario')} / {run.get('controller')}: collided={run.get('collided')} "
                f"t={run.get('collision_time')} min_distance={run.get('min_distance')} aeb={run.get('aeb_time')}"
            )
