"""Static plots of Scenarios (matplotlib, Agg backend, no pyplot state).

``plot_birdseye`` draws the world frame from above (x forward to the right, y left upwards,
equal scale, metres): the road (centre line, lane lines and edges), every processed trajectory
(solid where observed, dotted where extrapolated or stepped back), coloured by trajectory class,
the raw tracks as grey dots when a raw Scenario is given, start/end markers and the collision.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from deepcrashtest.fileio import atomic_path
from deepcrashtest.geometry.road import boundary_polylines
from deepcrashtest.scenario import Road, Scenario

CLASS_COLOURS = {
    "D0T1": "tab:green",
    "D0T2": "tab:olive",
    "D0T3": "tab:cyan",
    "D1T1": "tab:red",
    "D1T2": "tab:orange",
    "D1T3": "tab:purple",
    "D1T4": "tab:brown",
    None: "tab:gray",
}
EGO_COLOUR = "tab:blue"


def _draw_road(ax, road: Road) -> None:  # type: ignore[no-untyped-def]
    c = road.centerline()
    lines = boundary_polylines(road)
    lo, hi = lines[0], lines[-1]
    ax.fill(np.r_[lo[:, 0], hi[::-1, 0]], np.r_[lo[:, 1], hi[::-1, 1]], color="0.92", zorder=0)
    for q in lines[1:-1]:
        ax.plot(q[:, 0], q[:, 1], color="0.7", lw=0.6, ls=(0, (6, 6)), zorder=1)
    for q in (lo, hi):
        ax.plot(q[:, 0], q[:, 1], color="0.5", lw=0.8, zorder=1)
    ax.plot(c[:, 0], c[:, 1], color="0.6", lw=0.6, ls=":", zorder=1, label=f"road centre line ({road.source})")


def birdseye_figure(
    scenario: Scenario, raw: Scenario | None = None, title: str | None = None, margin_m: float = 40.0
) -> Figure:
    """The bird's-eye figure (see the module docstring). The view is the ego's path plus ``margin_m``
    metres on every side; what lies further out (long extrapolations) is cut off."""
    ex, ey = np.asarray(scenario.ego.trajectory.x), np.asarray(scenario.ego.trajectory.y)
    x_lo, x_hi = ex.min() - margin_m, ex.max() + margin_m
    y_lo, y_hi = ey.min() - margin_m, ey.max() + margin_m
    width = 16.0
    height = float(np.clip(width * (y_hi - y_lo) / (x_hi - x_lo), 3.0, 12.0)) + 1.5
    fig = Figure(figsize=(width, height), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    _draw_road(ax, scenario.road)
    if raw is not None:
        for v in raw.vehicles():
            ax.scatter(v.trajectory.x, v.trajectory.y, s=2, color="0.35", zorder=2, linewidths=0)
        ax.scatter([], [], s=6, color="0.35", label="raw tracks")
    seen: set[str | None] = set()
    for v in scenario.vehicles():
        a = v.trajectory.arrays()
        is_ego = v.id == scenario.ego.id
        colour = EGO_COLOUR if is_ego else CLASS_COLOURS.get(v.trajectory_class, "tab:gray")
        obs = np.asarray(v.trajectory.observed if v.trajectory.observed is not None else [True] * len(a["t"]))
        ax.plot(a["x"], a["y"], color=colour, lw=0.9, ls=":", zorder=3)
        xo, yo = np.where(obs, a["x"], np.nan), np.where(obs, a["y"], np.nan)
        key = "ego" if is_ego else v.trajectory_class
        label = None
        if key not in seen:
            seen.add(key)
            label = "ego" if is_ego else f"{key or 'unclassified'}"
        ax.plot(xo, yo, color=colour, lw=2.0 if is_ego else 1.4, zorder=4, label=label)
        ax.plot(a["x"][0], a["y"][0], "o", ms=3, color=colour, zorder=5)
        if not is_ego:
            k = int(np.argmax(obs)) if obs.any() else 0
            ax.annotate(str(v.id), (a["x"][k], a["y"][k]), fontsize=6, color=colour, zorder=6)
    ax.plot([], [], color="k", lw=0.9, ls=":", label="extrapolated / step-back")
    c = scenario.collision
    if c is not None and c.x is not None and c.y is not None:
        ax.plot([c.x], [c.y], "*", ms=14, color="red", zorder=7, label="collision")
    ax.set_xlim(x_lo, x_hi)
    ax.set_ylim(y_lo, y_hi)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("world x (forward), m")
    ax.set_ylabel("world y (left), m")
    t_max = scenario.provenance.parameters.get("t_max_s")
    default_title = f"{scenario.name}: {scenario.stage}" + (f", step-back t_max = {t_max:.2f} s" if t_max else "")
    ax.set_title(title or default_title)
    ax.legend(loc="upper left", fontsize=7, ncol=3)
    ax.grid(True, lw=0.3, alpha=0.5)
    fig.tight_layout()
    return fig


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
