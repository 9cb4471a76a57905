"""Static plots of Scenarios (matplotlib, Agg backend, no pyplot state), for the report and the demo.

``birdseye_figure`` draws the world frame from above (x forward to the right, y left upwards, equal
scale, metres): the road (:mod:`deepcrashtest.geometry.road`), every trajectory coloured by
class (:mod:`deepcrashtest.viz.style`), solid where observed in the video and dotted where
extrapolated, led in or stepped back, the raw tracks as grey dots when a raw Scenario is given,
start markers, ids and the collision. A long path (a KITTI drive over a kilometre) gets a second,
zoomed panel around the collision (or the video's end) so the road users stay readable.

``time_axes`` decorates a time plot (scenario time) with the video's span, the video time on a
second axis (the one mapping, :meth:`Scenario.video_time`) and optional marks (contact sheet frames).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from deepcrashtest.fileio import atomic_path
from deepcrashtest.geometry.road import boundary_polylines, divider_index, oncoming_polylines
from deepcrashtest.scenario import Scenario, Vehicle
from deepcrashtest.viz.style import EGO_COLOUR, vehicle_colour

#: Paths longer than this (metres, along x or y) get a zoomed panel.
LONG_PATH_M = 250.0
#: Half-size of the zoomed panel, metres (x, y).
ZOOM_HALF_M = (45.0, 22.0)
NOT_OBSERVED_STYLE: dict[str, Any] = {"ls": (0, (1.5, 1.5)), "alpha": 0.6}


def observed_mask(v: Vehicle) -> np.ndarray:
    """Per sample: True where seen in the video (all True when the trajectory does not say)."""
    tr = v.trajectory
    return np.ones(len(tr.t), bool) if tr.observed is None else np.asarray(tr.observed, bool)


def split_observed(values: np.ndarray, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``values`` where observed and where not (NaN elsewhere); the unobserved runs reach one sample into
    their observed neighbours so the two lines join."""
    v = np.asarray(values, float)
    unseen = ~obs | np.r_[~obs[1:], False] | np.r_[False, ~obs[:-1]]
    return np.where(obs, v, np.nan), np.where(unseen, v, np.nan)


def plot_observed(ax: Any, x: np.ndarray, y: np.ndarray, obs: np.ndarray, colour: str, lw: float, **kw: Any) -> None:
    """A line solid where ``obs`` and dotted/faded where not."""
    seen, unseen = split_observed(y, obs)
    ax.plot(x, seen, color=colour, lw=lw, **kw)
    kw.pop("label", None)
    if not obs.all():
        ax.plot(x, unseen, color=colour, lw=max(lw * 0.8, 0.7), **NOT_OBSERVED_STYLE, **kw)


def draw_road(ax: Any, sc: Scenario) -> None:
    """Road surface and lane lines of the ego's carriageway and the oncoming lanes (world frame, metres;
    :mod:`deepcrashtest.geometry.road`); the edge between the two directions solid and darker."""
    oncoming = oncoming_polylines(sc.road)
    own_divider = divider_index(sc.road)  # the ego carriageway's edge next to the oncoming lanes
    for b in (boundary_polylines(sc.road), oncoming):
        if not b:
            continue
        outline = np.vstack([b[0], b[-1][::-1]])
        ax.fill(outline[:, 0], outline[:, 1], color="0.9", zorder=0)
        for i, line in enumerate(b):
            style = {"lw": 0.9, "ls": "-"} if i in (0, len(b) - 1) else {"lw": 0.6, "ls": (0, (6, 6))}
            divider = bool(oncoming) and line is (b[0] if b is oncoming else b[own_divider])
            ax.plot(line[:, 0], line[:, 1], color="0.3" if divider else "0.55", zorder=1, **style)


def _draw_scene(
    ax: Any, sc: Scenario, raw: Scenario | None, sim_paths: Mapping[int, np.ndarray] | None, labels: bool
) -> None:
    draw_road(ax, sc)
    if raw is not None:
        for v in raw.vehicles():
            ax.scatter(v.trajectory.x, v.trajectory.y, s=2, color="0.35", zorder=2, linewidths=0)
    for v in sc.vehicles():
        a = v.trajectory.arrays()
        is_ego = v.id == sc.ego.id
        colour = vehicle_colour(v, sc.ego.id)
        obs = observed_mask(v)
        plot_observed(ax, a["x"], a["y"], obs, colour, 2.0 if is_ego else 1.3, zorder=4 if is_ego else 3)
        ax.plot(a["x"][0], a["y"][0], "o", ms=3, color=colour, zorder=5)
        if labels and not is_ego:
            k = int(np.argmax(obs)) if obs.any() else 0
            tag = f"{v.id}" if v.category in ("car", "van", "truck", "bus") else f"{v.id} {v.category}"
            ax.annotate(tag, (a["x"][k], a["y"][k]), fontsize=7, color="#222", zorder=6)
    if sim_paths:
        for path in sim_paths.values():
            p = np.asarray(path, float)
            ax.plot(p[:, 0], p[:, 1], color="k", lw=0.8, ls="--", zorder=4)
    c = sc.collision
    if c is not None and c.x is not None and c.y is not None:
        ax.plot([c.x], [c.y], "X", ms=11, color="red", mec="k", zorder=7)


def _legend_handles(sc: Scenario, raw: bool, sim: bool) -> tuple[list[Any], list[str]]:
    from matplotlib.lines import Line2D

    from deepcrashtest.viz.style import CLASS_SHORT

    handles: list[Any] = [Line2D([], [], color=EGO_COLOUR, lw=2)]
    names = ["ego"]
    for v in sorted(sc.agents, key=lambda a: a.trajectory_class or "~"):
        key = v.trajectory_class or "unclassified"
        text = f"{key} {CLASS_SHORT.get(key, '')}".strip()
        if text not in names:
            handles.append(Line2D([], [], color=vehicle_colour(v, sc.ego.id), lw=2))
            names.append(text)
    handles.append(Line2D([], [], color="0.3", lw=1.2, **NOT_OBSERVED_STYLE))
    names.append("not observed (extrapolated, lead-in, step-back)")
    if raw:
        handles.append(Line2D([], [], color="0.35", marker=".", ls=""))
        names.append("raw tracks")
    if sim:
        handles.append(Line2D([], [], color="k", lw=0.8, ls="--"))
        names.append("simulated")
    if sc.collision is not None and sc.collision.x is not None:
        handles.append(Line2D([], [], color="red", marker="X", mec="k", ls=""))
        names.append(f"collision ({sc.collision.source})")
    return handles, names


def view_extent(sc: Scenario, margin_m: float = 40.0, pad_m: float = 8.0) -> tuple[float, float, float, float]:
    """x_lo, x_hi, y_lo, y_hi (m): the ego's path and every observed position, ``pad_m`` around them, but no
    more than ``margin_m`` beyond the ego's path (long extrapolations are cut off)."""
    ex, ey = np.asarray(sc.ego.trajectory.x), np.asarray(sc.ego.trajectory.y)
    xs, ys = [ex], [ey]
    for v in sc.agents:
        obs = observed_mask(v)
        xs.append(np.asarray(v.trajectory.x)[obs])
        ys.append(np.asarray(v.trajectory.y)[obs])
    x, y = np.concatenate(xs), np.concatenate(ys)
    return (
        max(x.min() - pad_m, ex.min() - margin_m),
        min(x.max() + pad_m, ex.max() + margin_m),
        max(y.min() - pad_m, ey.min() - margin_m),
        min(y.max() + pad_m, ey.max() + margin_m),
    )


def zoom_centre(sc: Scenario) -> tuple[float, float]:
    """Where the zoomed panel looks: the collision, else the ego at the end of the video (or of its path)."""
    c = sc.collision
    if c is not None and c.x is not None and c.y is not None:
        return c.x, c.y
    t_end = sc.frame_time(max(sc.source.frame_count - 1, 0)) if sc.source.frame_count else sc.ego.trajectory.t[-1]
    st = sc.ego.trajectory.state_at(min(t_end, sc.ego.trajectory.t[-1]))
    return st["x"], st["y"]


def birdseye_figure(
    scenario: Scenario,
    raw: Scenario | None = None,
    title: str | None = None,
    margin_m: float = 40.0,
    sim_paths: Mapping[int, np.ndarray] | None = None,
) -> Figure:
    """The bird's-eye figure (see the module docstring); the view is :func:`view_extent`."""
    x_lo, x_hi, y_lo, y_hi = view_extent(scenario, margin_m)
    long = max(x_hi - x_lo, y_hi - y_lo) - 2 * margin_m > LONG_PATH_M
    width = 12.0
    over_h = float(np.clip(width * (y_hi - y_lo) / (x_hi - x_lo), 2.2, 9.0))
    zoom_h = width * ZOOM_HALF_M[1] / ZOOM_HALF_M[0] if long else 0.0
    fig = Figure(figsize=(width, over_h + zoom_h + 1.6), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 1, height_ratios=[over_h, zoom_h]) if long else [fig.add_subplot(1, 1, 1)]
    ax = axes[0]
    _draw_scene(ax, scenario, raw, sim_paths, labels=not long)
    ax.set_xlim(x_lo, x_hi)
    ax.set_ylim(y_lo, y_hi)
    if long:
        cx, cy = zoom_centre(scenario)
        zx, zy = ZOOM_HALF_M
        zax = axes[1]
        _draw_scene(zax, scenario, raw, sim_paths, labels=True)
        zax.set_xlim(cx - zx, cx + zx)
        zax.set_ylim(cy - zy, cy + zy)
        zax.set_aspect("equal", adjustable="box")
        where = (
            "the collision"
            if scenario.collision is not None and scenario.collision.x is not None
            else "the video's end"
        )
        zax.set_title(f"zoom: {2 * zx:g} m x {2 * zy:g} m around {where}", fontsize=9)
        ax.indicate_inset((cx - zx, cy - zy, 2 * zx, 2 * zy), inset_ax=zax, edgecolor="k", lw=1.0)
    for a in axes:
        a.set_aspect("equal", adjustable="box")
        a.set_xlabel("world x, forward (m)")
        a.set_ylabel("world y, left (m)")
        a.grid(True, lw=0.3, alpha=0.5)
    t_max = scenario.provenance.parameters.get("t_max_s")
    default_title = f"{scenario.name}: {scenario.stage}" + (f", step-back t_max = {t_max:.2f} s" if t_max else "")
    ax.set_title(title or default_title)
    handles, names = _legend_handles(scenario, raw is not None, bool(sim_paths))
    fig.legend(handles, names, loc="outside lower center", ncols=min(4, len(names)), fontsize=8)
    return fig


def time_axes(
    ax: Any, sc: Scenario, marks: Sequence[tuple[str, float]] = (), video: bool = True, top_axis: bool = True
) -> None:
    """Shade the video's span on a scenario-time axis, mark the collision and ``marks`` (label, scenario
    time), and add the video time on top (``top_axis``)."""
    if video and sc.source.frame_count > 0:
        a, b = sc.frame_time(0), sc.frame_time(sc.source.frame_count)
        ax.axvspan(a, b, color="#1e88e5", alpha=0.08, lw=0, zorder=0)
        if top_axis:
            sec = ax.secondary_xaxis("top", functions=(sc.video_time, sc.scenario_time))
            sec.set_xlabel("video time (s); shaded: the video", fontsize=8)
            sec.tick_params(labelsize=7)
    if sc.collision is not None:
        ax.axvline(sc.collision.time_s, color="red", lw=1.0, ls="--", zorder=1)
    for text, t in marks:
        ax.axvline(t, color="0.5", lw=0.5, ls=":", zorder=1)
        ax.annotate(
            text, (t, 1.0), xycoords=("data", "axes fraction"), fontsize=6, color="0.3", ha="center", va="bottom"
        )


def plot_birdseye(
    scenario: Scenario,
    raw: Scenario | None = None,
    path: str | os.PathLike[str] | None = None,
    *,
    force: bool = False,
    title: str | None = None,
    margin_m: float = 40.0,
) -> Path | Figure:
    """Bird's-eye PNG of ``scenario`` (optionally over the ``raw`` tracks), written atomically to
    ``path`` (refused if it exists, unless ``force``); returns the path, or the Figure if no path."""
    fig = birdseye_figure(scenario, raw, title, margin_m)
    if path is None:
        return fig
    with atomic_path(path, force=force, suffix=".png") as tmp:
        fig.savefig(tmp, format="png")
    return Path(path)
