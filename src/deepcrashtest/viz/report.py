"""``report.html``: one self-contained HTML file describing a run (images inline as base64 PNG).

Composable: each ``*_section`` builder returns a :class:`Section` (or None when it has nothing to
show), and :func:`write_report` puts any sequence of them into one file. Extraction, simulation and
the search each add the sections they know about; :func:`scenario_sections` builds the ones a
Scenario file (plus optional video, simulation metrics and search table) can give.

Plots use matplotlib's Agg canvas directly (no pyplot state), world frame x forward / y left,
metres and seconds.
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from deepcrashtest import __version__
from deepcrashtest.errors import UserError
from deepcrashtest.fileio import atomic_write_text
from deepcrashtest.geometry.road import lane_lines
from deepcrashtest.scenario import TRAJECTORY_CLASSES, Scenario, Vehicle

EGO_COLOUR = "#d32f2f"
CLASS_COLOURS = dict(
    zip(TRAJECTORY_CLASSES, ("#1e88e5", "#00acc1", "#3949ab", "#fbc02d", "#fb8c00", "#8e24aa", "#6d4c41"), strict=True)
)
UNCLASSIFIED_COLOUR = "#78909c"


@dataclass
class Section:
    """One part of the report: a title and its body (HTML built by the builders, text escaped)."""

    title: str
    body: str

    @property
    def anchor(self) -> str:
        return "".join(c if c.isalnum() else "-" for c in self.title.lower()).strip("-")


# --------------------------------------------------------------------------- HTML pieces
def esc(value: Any) -> str:
    return html.escape(str(value), quote=True)


def fmt(value: Any, digits: int = 3) -> str:
    """A number rounded for people; None/NaN as a dash."""
    if value is None:
        return "-"
    if isinstance(value, bool | np.bool_):
        return "yes" if value else "no"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        return "-" if not math.isfinite(float(value)) else f"{float(value):.{digits}g}"
    return str(value)


def table(rows: Iterable[tuple[str, Any]]) -> str:
    """A two-column key/value table (values formatted with :func:`fmt`, escaped)."""
    cells = "".join(f"<tr><th>{esc(k)}</th><td>{esc(fmt(v))}</td></tr>" for k, v in rows)
    return f'<table class="kv">{cells}</table>'


def figure_png(fig: Any) -> str:
    """Base64 PNG of a matplotlib Figure (rendered with the Agg canvas)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=fig.dpi, bbox_inches="tight")
    return base64.b64encode(buf.getvalue()).decode("ascii")


def img(png_b64: str, alt: str) -> str:
    return f'<img alt="{esc(alt)}" src="data:image/png;base64,{png_b64}">'


def _figure(width: float, height: float) -> Any:
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), dpi=100, layout="constrained")


def vehicle_colour(v: Vehicle, ego_id: int) -> str:
    if v.id == ego_id:
        return EGO_COLOUR
    return CLASS_COLOURS.get(v.trajectory_class or "", UNCLASSIFIED_COLOUR)


# --------------------------------------------------------------------------- sections
def overview_section(sc: Scenario) -> Section:
    """Name, stage, vehicles, duration, classes, collision and provenance."""
    classes = sc.class_counts()
    rows: list[tuple[str, Any]] = [
        ("name", sc.name),
        ("schema version", sc.schema_version),
        ("stage", sc.stage),
        ("agents", len(sc.agents)),
        ("duration (s)", sc.duration()),
        ("road users", category_listing(sc)),
        ("trajectory classes", ", ".join(f"{k}: {n}" for k, n in classes.items()) or "-"),
        (
            "road",
            f"{sc.road.lane_count} lanes x {sc.road.lane_width:g} m, ego lane {sc.road.ego_lane}, "
            f"from {sc.road.source}"
            + (" (no lanes seen: inferred from the road users' paths)" if sc.road.source == "road_users" else ""),
        ),
    ]
    if sc.collision is not None:
        c = sc.collision
        names = {v.id: ("ego" if v.id == sc.ego.id else f"{v.category} {v.id}") for v in sc.vehicles()}
        kind = "" if c.involves_ego else " (third-party crash)"
        rows.append(
            (
                "collision in the video",
                f"t={c.time_s:.2f} s, {names[c.other_id]} with {names[c.agent_id]}{kind}, source {c.source}",
            )
        )
    rows += [
        ("made by", f"deepcrashtest {sc.provenance.package_version}: {sc.provenance.command or '-'}"),
        ("parameters", ", ".join(f"{k}={v}" for k, v in sc.provenance.parameters.items()) or "-"),
        ("seed", sc.provenance.seed),
    ]
    body = table(rows)
    if sc.provenance.history:
        body += "<h3>Edit history</h3><ol>" + "".join(f"<li>{esc(h)}</li>" for h in sc.provenance.history) + "</ol>"
    return Section("Scenario", body)


def category_listing(sc: Scenario) -> str:
    """Agents per road-user category, e.g. ``car: 3, motorcycle (with rider): 1, pedestrian: 2``."""
    counts: dict[str, int] = {}
    for a in sc.agents:
        counts[a.category] = counts.get(a.category, 0) + 1
    order = ("car", "van", "truck", "bus", "motorcycle", "bicycle", "pedestrian")
    label = {"motorcycle": "motorcycle (with rider)", "bicycle": "bicycle (with rider)"}
    return ", ".join(f"{label.get(k, k)}: {counts[k]}" for k in order if k in counts) or "-"


def source_section(sc: Scenario) -> Section:
    """Facts about the source video (or label file) the scenario came from."""
    s = sc.source
    rows: list[tuple[str, Any]] = [
        ("kind", s.kind),
        ("file", Path(s.path).name),
        ("frame rate (fps)", s.fps),
        ("frames", s.frame_count),
        ("length (s)", s.frame_count / s.fps),
        ("size (px)", f"{s.width} x {s.height}"),
        ("SHA-256", s.sha256 or "-"),
    ]
    if s.frame_rate_note:
        rows.append(("frame-rate note", s.frame_rate_note))
    return Section("Source video", table(rows))


def camera_section(sc: Scenario) -> Section:
    """The camera model and where each of its calibration values came from."""
    c = sc.camera
    rows: list[tuple[str, Any]] = [
        ("focal length fx, fy (px)", f"{c.fx:.1f}, {c.fy:.1f}"),
        ("principal point cx, cy (px)", f"{c.cx:.1f}, {c.cy:.1f}"),
        ("horizontal field of view (deg)", math.degrees(2 * math.atan(sc.source.width / (2 * c.fx)))),
        ("distortion", ", ".join(f"{d:.4g}" for d in c.distortion) or "none"),
        ("intrinsics from", c.intrinsics_source),
        ("height above road (m)", c.height_m),
        ("height from", c.height_source),
        ("pitch, down + (deg)", math.degrees(c.pitch_rad)),
        ("pitch from", c.pitch_source),
        ("roll (deg)", math.degrees(c.roll_rad)),
        ("ahead of ego centre (m)", c.forward_offset_m),
    ]
    return Section("Camera and calibration", table(rows))


def contact_sheet_section(video: str | Path, frames: int = 12, columns: int = 4, thumb_width: int = 320) -> Section:
    """A grid of ``frames`` evenly spaced frames of ``video`` (the annotated extraction output)."""
    import cv2

    from deepcrashtest.viz.video_frames import VideoFrames

    if frames < 1 or columns < 1:
        raise UserError(f"contact sheet needs frames >= 1 and columns >= 1 (got {frames}, {columns})")
    vf = VideoFrames(video)
    try:
        times = (np.arange(frames) + 0.5) * vf.duration_s / frames
        thumbs = []
        for t in times:
            rgb = vf.frame_at(float(t))
            h, w = rgb.shape[:2]
            thumbs.append(cv2.resize(rgb, (thumb_width, round(h * thumb_width / w)), interpolation=cv2.INTER_AREA))
        info = vf.info()
    finally:
        vf.close()
    rows = math.ceil(frames / columns)
    th, tw = thumbs[0].shape[:2]
    fig = _figure(columns * tw / 100, rows * (th + 24) / 100)
    axes = fig.subplots(rows, columns, squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, t, im in zip(axes.ravel(), times, thumbs, strict=False):
        ax.imshow(im)
        ax.set_title(f"t = {t:.2f} s (frame {int(t * vf.fps)})", fontsize=8)
    caption = (
        f"<p>{esc(Path(video).name)}: {info['width']} x {info['height']} px, {info['fps']:.3g} fps, "
        f"{info['duration_s']:.2f} s, {frames} frames evenly spaced.</p>"
    )
    return Section("Annotated frames", caption + img(figure_png(fig), "contact sheet of annotated frames"))


def draw_road(ax: Any, sc: Scenario) -> None:
    """Road surface and lane lines on a matplotlib Axes (world frame)."""
    lines = lane_lines(sc.road)
    b = [np.asarray(line) for line in lines["boundaries"]]
    outline = np.vstack([b[0], b[-1][::-1]])
    ax.fill(outline[:, 0], outline[:, 1], color="#d9d9d9", zorder=0)
    for i, line in enumerate(b):
        outer = i in (0, len(b) - 1)
        ax.plot(line[:, 0], line[:, 1], color="#555", lw=1.0 if outer else 0.7, ls="-" if outer else "--", zorder=1)


def birdseye_section(sc: Scenario, sim_states: Mapping[int, np.ndarray] | None = None) -> Section:
    """Bird's-eye plot of every trajectory on the road, coloured by trajectory class.

    ``sim_states``: optional simulated paths per vehicle id ((T, 2+) arrays, x, y first), drawn dashed.
    """
    from matplotlib.lines import Line2D

    fig = _figure(10, 4.8)
    ax = fig.add_subplot()
    draw_road(ax, sc)
    used: dict[str, str] = {}
    for v in sc.vehicles():
        tr = v.trajectory.arrays()
        col = vehicle_colour(v, sc.ego.id)
        label = "ego" if v.id == sc.ego.id else (v.trajectory_class or "unclassified")
        used[label] = col
        ax.plot(tr["x"], tr["y"], color=col, lw=2.2 if v.id == sc.ego.id else 1.2, zorder=3)
        ax.plot(tr["x"][0], tr["y"][0], "o", color=col, ms=3, zorder=4)
        if v.id != sc.ego.id:
            tag = f"{v.id}" if v.category in ("car", "van", "truck", "bus") else f"{v.id} {v.category}"
            ax.annotate(tag, (tr["x"][0], tr["y"][0]), fontsize=6, color="#333", zorder=5)
    if sim_states:
        for path in sim_states.values():
            p = np.asarray(path, float)
            ax.plot(p[:, 0], p[:, 1], color="k", lw=0.8, ls=":", zorder=4)
        used["simulated"] = "k"
    if sc.collision is not None and sc.collision.x is not None and sc.collision.y is not None:
        ax.plot(sc.collision.x, sc.collision.y, "X", color="k", ms=10, zorder=6)
    handles = [Line2D([], [], color=c, lw=2, ls=":" if k == "simulated" else "-") for k, c in used.items()]
    ax.legend(handles, list(used), fontsize=7, loc="best", ncols=2)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x forward (m)")
    ax.set_ylabel("y left (m)")
    ax.grid(alpha=0.3)
    body = "<p>Dots mark where each vehicle is first seen; numbers are vehicle ids.</p>"
    return Section("Bird's-eye view", body + img(figure_png(fig), "bird's-eye plot of the trajectories"))


def distance_to_ego(sc: Scenario, v: Vehicle) -> tuple[np.ndarray, np.ndarray]:
    """Times (s) and centre-to-centre distance (m) from the ego, where both exist."""
    a, e = v.trajectory.arrays(), sc.ego.trajectory.arrays()
    keep = (a["t"] >= e["t"][0]) & (a["t"] <= e["t"][-1])
    t = a["t"][keep]
    d = np.hypot(a["x"][keep] - np.interp(t, e["t"], e["x"]), a["y"][keep] - np.interp(t, e["t"], e["y"]))
    return t, d


def motion_section(sc: Scenario) -> Section:
    """Speed of every vehicle, and each agent's distance from the ego, over time."""
    fig = _figure(10, 5.5)
    ax_v, ax_d = fig.subplots(2, 1, sharex=True)
    for v in sc.vehicles():
        tr = v.trajectory.arrays()
        col = vehicle_colour(v, sc.ego.id)
        is_ego = v.id == sc.ego.id
        ax_v.plot(tr["t"], tr["speed"] * 3.6, color=col, lw=2.0 if is_ego else 0.9, label="ego" if is_ego else None)
        if not is_ego:
            t, d = distance_to_ego(sc, v)
            ax_d.plot(t, d, color=col, lw=0.9)
            if len(t):
                i = int(np.argmin(d))
                ax_d.annotate(str(v.id), (t[i], d[i]), fontsize=6, color="#333")
    ax_v.set_ylabel("speed (km/h)")
    ax_v.legend(fontsize=7, loc="upper right")
    ax_d.set_ylabel("distance to ego (m)")
    ax_d.set_xlabel("time (s)")
    for ax in (ax_v, ax_d):
        ax.grid(alpha=0.3)
    closest = []
    for v in sc.agents:
        t, d = distance_to_ego(sc, v)
        if len(t):
            i = int(np.argmin(d))
            closest.append((float(d[i]), v.id, float(t[i])))
    closest.sort()
    rows = [(f"vehicle {vid}", f"{d:.2f} m at t={t:.2f} s") for d, vid, t in closest[:5]]
    body = img(figure_png(fig), "speed and distance over time")
    if rows:
        body += "<h3>Closest approaches (centre to centre)</h3>" + table(rows)
    return Section("Speed and distance over time", body)


def lane_offset_section(sc: Scenario) -> Section | None:
    """The ego's lateral offset in its lane and its lane index over time (None without a lane timeline)."""
    lt = sc.road.lane_timeline
    if lt is None or not lt.t:
        return None
    fig = _figure(10, 3.2)
    ax = fig.add_subplot()
    ax.plot(lt.t, lt.lateral_offset, color=EGO_COLOUR, lw=1.5, label="offset from lane centre")
    for edge in (-sc.road.lane_width / 2, sc.road.lane_width / 2):
        ax.axhline(edge, color="#555", ls="--", lw=0.8)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("left of lane centre (m)")
    ax2 = ax.twinx()
    ax2.step(lt.t, lt.lane_index, where="post", color="#1e88e5", lw=1.0, label="lane index")
    ax2.set_ylabel("lane (0 = rightmost)")
    ax2.set_yticks(range(sc.road.lane_count))
    ax.grid(alpha=0.3)
    changes = int(np.count_nonzero(np.diff(np.asarray(lt.lane_index))))
    body = f"<p>{changes} lane change(s). Dashed lines: the lane's edges.</p>"
    return Section("Lane offset", body + img(figure_png(fig), "lane offset over time"))


def simulation_section(metrics: Mapping[str, Any] | Any, title: str = "Simulation outcome") -> Section:
    """A table of simulation metrics (a dict, or anything with a ``.metrics`` dict such as a SimResult)."""
    m = getattr(metrics, "metrics", metrics)
    if not isinstance(m, Mapping):
        raise UserError(f"simulation metrics must be a JSON object, got {type(m).__name__}")
    first = ("collided", "collision_time", "collision_vehicle", "delta_v_ego", "relative_speed", "min_distance")
    keys = [k for k in first if k in m] + sorted(k for k in m if k not in first)
    units = {
        "collision_time": "s",
        "delta_v_ego": "m/s",
        "relative_speed": "m/s",
        "min_distance": "m",
        "min_ttc": "s",
        "aeb_time": "s",
        "warning_time": "s",
        "robustness": "m",
    }
    rows = [(f"{k.replace('_', ' ')}" + (f" ({units[k]})" if k in units else ""), m[k]) for k in keys]
    verdict = "collision" if m.get("collided") else "no collision"
    return Section(title, f'<p class="verdict">{esc(verdict)}</p>' + table(rows))


def _search_columns(df: Any) -> Any:
    cols = {c.lower(): c for c in df.columns}
    ren = {}
    for want, aliases in (("dx", ("dx", "d_lon")), ("dy", ("dy", "d_lat"))):
        src = next((cols[a] for a in aliases if a in cols), None)
        if src is None:
            raise UserError(f"search table needs a column {want} (or {'/'.join(aliases[1:])}); has {list(df.columns)}")
        ren[src] = want
    for need in ("collided", "robustness"):
        if need not in df.columns:
            raise UserError(f"search table needs a column {need}; has {list(df.columns)}")
    return df.rename(columns=ren)


def search_section(results: Any, title: str = "Search: start positions") -> Section:
    """Start-position map coloured by outcome, with safe-variant counts.

    ``results``: a DataFrame (or a path to a CSV) with columns dx, dy (ego start offset, m;
    ``d_lon``/``d_lat`` accepted), collided (bool) and robustness (m, minimum separation, negative
    on collision). A variant is safe when it does not collide (or per a ``safe`` column if given).
    """
    import pandas as pd

    df = pd.read_csv(results) if isinstance(results, str | Path) else results
    df = _search_columns(df)
    if df.empty:
        return Section(title, "<p>The search table is empty.</p>")
    collided = df["collided"].astype(str).str.lower().isin(["true", "1", "1.0", "yes"]).to_numpy()
    safe = (
        df["safe"].astype(str).str.lower().isin(["true", "1", "1.0", "yes"]).to_numpy()
        if "safe" in df.columns
        else ~collided
    )
    rob = pd.to_numeric(df["robustness"], errors="coerce").to_numpy(float)
    fig = _figure(8, 5)
    ax = fig.add_subplot()
    from matplotlib.colors import TwoSlopeNorm

    finite = rob[np.isfinite(rob)]
    # red below zero (contact), green above: centre the colour scale on zero when it is inside the range
    norm = TwoSlopeNorm(0.0) if finite.size and finite.min() < 0 < finite.max() else None
    sc_plot = ax.scatter(df["dx"], df["dy"], c=rob, cmap="RdYlGn", norm=norm, s=22, edgecolors="none", zorder=2)
    ax.scatter(df["dx"][collided], df["dy"][collided], marker="x", c="k", s=18, lw=0.8, zorder=3, label="collided")
    ax.scatter([0], [0], marker="*", c="#d32f2f", s=120, zorder=4, label="original start")
    fig.colorbar(sc_plot, ax=ax, label="robustness (m)")
    ax.set_xlabel("start offset, longitudinal dx (m)")
    ax.set_ylabel("start offset, lateral dy (m)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    rows: list[tuple[str, Any]] = [
        ("variants simulated", len(df)),
        ("safe variants", int(safe.sum())),
        ("collided variants", int(collided.sum())),
        ("safe share", float(safe.mean())),
        (
            "robustness min / median / max (m)",
            "-" if not finite.size else f"{finite.min():.2f} / {np.median(finite):.2f} / {finite.max():.2f}",
        ),
    ]
    return Section(title, table(rows) + img(figure_png(fig), "start-position map coloured by outcome"))


def warnings_section(sc: Scenario) -> Section | None:
    if not sc.warnings:
        return None
    return Section("Warnings", "<ul>" + "".join(f"<li>{esc(w)}</li>" for w in sc.warnings) + "</ul>")


def scenario_sections(
    sc: Scenario,
    video: str | Path | None = None,
    sim_metrics: Mapping[str, Any] | Any | None = None,
    search: Any | None = None,
) -> list[Section]:
    """Every section a scenario (+ optional annotated video, simulation metrics, search table) gives."""
    parts: list[Section | None] = [
        overview_section(sc),
        warnings_section(sc),
        source_section(sc),
        camera_section(sc),
        contact_sheet_section(video) if video is not None else None,
        birdseye_section(sc),
        motion_section(sc),
        lane_offset_section(sc),
        simulation_section(sim_metrics) if sim_metrics is not None else None,
        search_section(search) if search is not None else None,
    ]
    return [p for p in parts if p is not None]


# --------------------------------------------------------------------------- the file
_CSS = """
body{font:14px/1.45 system-ui,sans-serif;margin:0 auto;max-width:1100px;padding:1em 2em;color:#222}
h1{margin-bottom:0}.meta{color:#666;margin-top:.2em}
h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}
table.kv{border-collapse:collapse}table.kv th{text-align:left;padding:2px 14px 2px 0;color:#555;font-weight:600}
table.kv td{font-family:ui-monospace,monospace;padding:2px 0}img{max-width:100%;display:block;margin:.6em 0}
nav a{margin-right:1em}.verdict{font-size:1.2em;font-weight:bold}
"""


def render_report(sections: Iterable[Section | None], title: str = "DeepCrashTest report") -> str:
    """The report as one HTML string (None sections are skipped)."""
    parts = [s for s in sections if s is not None]
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    nav = "".join(f'<a href="#{s.anchor}">{esc(s.title)}</a>' for s in parts)
    body = "".join(f'<section id="{s.anchor}"><h2>{esc(s.title)}</h2>{s.body}</section>' for s in parts)
    return (
        f'<!doctype html><html lang="en"><head><meta charset="utf-8"><title>{esc(title)}</title>'
        f"<style>{_CSS}</style></head><body><h1>{esc(title)}</h1>"
        f'<p class="meta">deepcrashtest {esc(__version__)}, {stamp}</p><nav>{nav}</nav>{body}</body></html>\n'
    )


def write_report(
    path: str | Path, *sections: Section | None, title: str = "DeepCrashTest report", force: bool = False
) -> Path:
    """Write the sections as one self-contained HTML file, atomically (refuses to overwrite unless ``force``)."""
    return atomic_write_text(path, render_report(sections, title), force=force)


#: Optional files looked for beside a scenario file by :func:`build_report`.
BESIDE_VIDEO = ("annotated.mp4",)
BESIDE_SIM = ("simulation.json",)
BESIDE_SEARCH = ("results.csv", "search/results.csv")


def load_sim_metrics(path: str | Path) -> dict[str, Any]:
    """Metrics from a JSON file: a metrics object, or ``deepcrashtest simulate --json`` output (``metrics`` key)."""
    import json

    from deepcrashtest.fileio import require_file

    p = require_file(path, "simulation metrics file")
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise UserError(f"{p}: not a JSON file ({exc})") from None
    m = data.get("metrics", data) if isinstance(data, dict) else data
    if not isinstance(m, dict):
        raise UserError(f"{p}: expected a JSON object of simulation metrics")
    return m


def _beside(folder: Path, names: tuple[str, ...]) -> Path | None:
    return next((folder / n for n in names if (folder / n).is_file()), None)


def build_report(
    scenario: str | Path,
    output: str | Path,
    video: str | Path | None = None,
    sim: str | Path | None = None,
    search: str | Path | None = None,
    force: bool = False,
    sim_metrics: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Write the report of a scenario file; optional inputs default to the files beside it.

    ``sim_metrics`` (a metrics dict from a run made by the caller) takes the place of ``sim``.

    Beside the scenario: ``annotated.mp4`` (contact sheet), ``simulation.json`` (metrics, e.g.
    ``deepcrashtest simulate --json`` output), ``results.csv`` or ``search/results.csv`` (search table).
    """
    from deepcrashtest.fileio import check_writable, require_file

    check_writable(output, force)  # fail before the work, not after
    sc_path = Path(scenario)
    sc = Scenario.load(sc_path)
    folder = sc_path.resolve().parent
    video_p = Path(video) if video is not None else _beside(folder, BESIDE_VIDEO)
    sim_p = Path(sim) if sim is not None else None if sim_metrics is not None else _beside(folder, BESIDE_SIM)
    search_p = Path(search) if search is not None else _beside(folder, BESIDE_SEARCH)
    if video_p is not None:
        require_file(video_p, "video")
    if search_p is not None:
        require_file(search_p, "search table")
    sections = scenario_sections(
        sc,
        video=video_p,
        sim_metrics=load_sim_metrics(sim_p) if sim_p is not None else sim_metrics,
        search=search_p,
    )
    path = write_report(output, *sections, title=f"DeepCrashTest report: {sc.name}", force=force)
    return {
        "report": str(path),
        "sections": [s.title for s in sections],
        "video": None if video_p is None else str(video_p),
        "simulation": str(sim_p) if sim_p is not None else "given" if sim_metrics is not None else None,
        "search": None if search_p is None else str(search_p),
        "bytes": path.stat().st_size,
    }
