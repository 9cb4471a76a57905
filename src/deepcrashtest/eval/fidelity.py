"""Reconstruction fidelity: is the scenario (and its simulated replay) the video it came from?

Two measurements (``evaluate_fidelity``):

* **Reprojection.** For every tracked box (``tracks.csv``: one row per track per video frame; a
  track's id is the scenario agent's id) the agent's 3D box is projected into the original camera
  (:mod:`deepcrashtest.geometry.project`) with the scenario's camera and the ego pose at that time,
  (a) from the processed scenario's trajectories and (b) from the simulated replay's states, and
  compared with the tracked box: IoU and centre error (pixels). A pair counts when the agent exists
  at that time (inside its trajectory's span / present in the replay); a projection that misses the
  image scores IoU 0. Video frame -> scenario time only through ``Scenario.frame_time``.
  Only tracked boxes the detector anchors count (:func:`detection_anchored`): a track's boxes from
  its first to its last detection (the optical-flow boxes between detections included); the boxes
  the tracker coasts on after losing a road user (``state`` predicted after its last detection, up
  to its maximum age) are not video evidence: on the fidelity clips they slid onto the car that
  hid the lost one (ccd_000340 track 4 over the crashing car's windscreen, dad_000550 track 3
  over a truck). Their number is reported (``coasting_boxes_excluded``).
* **Crash.** The replay's first contact (any pair) against the labelled crash
  (:mod:`deepcrashtest.datasets.crash_labels`): same two participants, time error in video time,
  relative speed at contact, contacts before the labelled one. A labelled road user (a pixel box
  at the contact frame) is the tracked box that overlaps it most (IoU >= 0.3 within two frames).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from deepcrashtest.datasets.crash_labels import CrashLabel
from deepcrashtest.errors import UserError
from deepcrashtest.eval.plausibility import plausibility
from deepcrashtest.geometry.project import project_box, scenario_poses
from deepcrashtest.perception.boxes import iou_matrix
from deepcrashtest.scenario import Scenario

#: IoU at or above which a projected box "matches" its tracked box.
IOU_MATCH = 0.5
#: |time error| (s, video time) within which a simulated contact reproduces the labelled one.
CRASH_DT_S = 0.25
#: A labelled box is the tracked box overlapping it at least this much (within LABEL_FRAME_SLACK frames).
LABEL_TRACK_IOU = 0.3
LABEL_FRAME_SLACK = 2
TRACK_COLUMNS = ("frame", "track_id", "x1", "y1", "x2", "y2")
SOURCES = ("processed", "simulated")


@dataclass
class FidelityResult:
    """Per-pair table (``pairs``), summaries and the crash comparison; ``to_dict`` is the JSON form."""

    scenario: str
    time_mapping: dict[str, Any]
    pairs: pd.DataFrame
    reprojection: dict[str, Any]
    per_agent: dict[str, dict[str, Any]]
    crash: dict[str, Any]
    notes: list[str] = field(default_factory=list)
    plausibility: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "scenario": self.scenario,
            "time_mapping": self.time_mapping,
            "reprojection": self.reprojection,
            "per_agent": self.per_agent,
            "crash": self.crash,
            "plausibility": self.plausibility,
            "notes": self.notes,
        }


def read_tracks(path: str | Path) -> pd.DataFrame:
    """Read ``tracks.csv`` (columns of :data:`TRACK_COLUMNS` at least); bad files: one-line UserError."""
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{p}: tracks file not found")
    try:
        df = pd.read_csv(p)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise UserError(f"{p}: not a tracks CSV ({str(exc).splitlines()[0]})") from None
    missing = [c for c in TRACK_COLUMNS if c not in df.columns]
    if missing:
        raise UserError(f"{p}: tracks CSV misses columns {missing}")
    return df


def detection_anchored(tracks: pd.DataFrame) -> pd.DataFrame:
    """The rows of ``tracks`` from each track's first to its last ``detected`` row (all rows when the
    table has no ``state`` column; a track never detected keeps none). See the module docstring."""
    if "state" not in tracks.columns or not len(tracks):
        return tracks
    det = tracks[tracks["state"] == "detected"].groupby("track_id")["frame"].agg(["min", "max"])
    lo = tracks["track_id"].map(det["min"])
    hi = tracks["track_id"].map(det["max"])
    return tracks[(tracks["frame"] >= lo) & (tracks["frame"] <= hi)]


# --------------------------------------------------------------------------- poses
def _centre_error(a: np.ndarray, b: np.ndarray) -> float:
    return float(math.hypot(0.5 * (a[0] + a[2] - b[0] - b[2]), 0.5 * (a[1] + a[3] - b[1] - b[3])))


# --------------------------------------------------------------------------- reprojection
def reprojection_pairs(
    scenario: Scenario, tracks: pd.DataFrame, sim: Any | None = None, anchored: bool = True
) -> pd.DataFrame:
    """One row per detection-anchored tracked box (:func:`detection_anchored`; every tracked box when
    ``anchored`` is False) of an agent of ``scenario``: the tracked box, the projected boxes
    (processed, simulated) and their IoU / centre error (NaN where the agent does not exist then).

    Columns: frame, video_time, scenario_time, agent_id, category, anchored, x1..y2 (tracked), and per source
    ``{src}_box`` (array or None), ``{src}_iou``, ``{src}_centre_px``.
    """
    size = (scenario.source.width, scenario.source.height)
    agents = {a.id: a for a in scenario.agents}
    sim_col = {vid: i for i, vid in enumerate(sim.vehicle_ids)} if sim is not None else {}
    rows: list[dict[str, Any]] = []
    ego = scenario.ego
    pose_at = scenario_poses(scenario)
    kept = set(detection_anchored(tracks).index)
    for index, r in zip(tracks.index, tracks.itertuples(index=False), strict=True):
        agent = agents.get(int(r.track_id))  # type: ignore[arg-type]
        if agent is None or (anchored and index not in kept):
            continue
        frame = int(r.frame)  # type: ignore[arg-type]
        t = scenario.frame_time(frame)
        tracked = np.array([r.x1, r.y1, r.x2, r.y2], dtype=float)
        row: dict[str, Any] = {
            "frame": frame,
            "video_time": float(scenario.video_time(t)),
            "scenario_time": t,
            "agent_id": agent.id,
            "category": agent.category,
            "anchored": index in kept,
            "x1": tracked[0],
            "y1": tracked[1],
            "x2": tracked[2],
            "y2": tracked[3],
        }
        camera = scenario.camera.at_video_time(float(scenario.video_time(t)))  # its pitch and roll then
        poses = {"processed": (pose_at(ego.id, t), pose_at(agent.id, t))}
        if sim is not None and agent.id in sim_col:
            poses["simulated"] = (sim.pose_at(t, sim_col[ego.id]), sim.pose_at(t, sim_col[agent.id]))
        for src in SOURCES:
            ego_pose, pose = poses.get(src, (None, None))
            box = None
            iou = err = float("nan")
            if ego_pose is not None and pose is not None:
                pb = project_box(camera, ego_pose, *pose, agent.length, agent.width, agent.height, image_size=size)
                box = pb.box
                iou = float(iou_matrix(box, tracked)[0, 0]) if box is not None else 0.0
                err = _centre_error(box, tracked) if box is not None else float("nan")
            row[f"{src}_box"] = box
            row[f"{src}_iou"] = iou
            row[f"{src}_centre_px"] = err
        rows.append(row)
    return pd.DataFrame(rows)


def _stats(df: pd.DataFrame, src: str) -> dict[str, Any]:
    iou = df[f"{src}_iou"].to_numpy(float) if len(df) else np.zeros(0)
    ok = np.isfinite(iou)
    err = df[f"{src}_centre_px"].to_numpy(float) if len(df) else np.zeros(0)
    err = err[ok & np.isfinite(err)]
    n = int(ok.sum())
    return {
        "pairs": n,
        "coverage": round(n / len(iou), 4) if len(iou) else None,
        "mean_iou": round(float(iou[ok].mean()), 4) if n else None,
        "share_iou_ge_0_5": round(float((iou[ok] >= IOU_MATCH).mean()), 4) if n else None,
        "median_centre_px": round(float(np.median(err)), 2) if len(err) else None,
        **_offsets(df, src),
    }


def _offsets(df: pd.DataFrame, src: str) -> dict[str, float | None]:
    """Where the error comes from (medians over pairs with a projected box): the projected centre's offset
    right (``du``) and down (``dv``) of the tracked one, pixels, and projected / tracked width and height.
    A large ``dv`` points at the camera's pitch or height, width ratios >> 1 at headings."""
    keys = ("median_du_px", "median_dv_px", "median_width_ratio", "median_height_ratio")
    has = [b is not None for b in df[f"{src}_box"]] if len(df) else []
    if not any(has):
        return dict.fromkeys(keys)
    sel = df[has]
    b = np.stack(list(sel[f"{src}_box"]))
    t = sel[["x1", "y1", "x2", "y2"]].to_numpy(float)
    du = 0.5 * (b[:, 0] + b[:, 2] - t[:, 0] - t[:, 2])
    dv = 0.5 * (b[:, 1] + b[:, 3] - t[:, 1] - t[:, 3])
    wr = (b[:, 2] - b[:, 0]) / np.maximum(t[:, 2] - t[:, 0], 1.0)
    hr = (b[:, 3] - b[:, 1]) / np.maximum(t[:, 3] - t[:, 1], 1.0)
    return {k: round(float(np.median(v)), 3) for k, v in zip(keys, (du, dv, wr, hr), strict=True)}


def summarise_reprojection(pairs: pd.DataFrame) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """Overall and per-agent statistics of :func:`reprojection_pairs` for both sources."""
    overall: dict[str, Any] = {"tracked_boxes": len(pairs)}
    overall.update({src: _stats(pairs, src) for src in SOURCES})
    per: dict[str, dict[str, Any]] = {}
    if len(pairs):
        for aid, g in pairs.groupby("agent_id"):
            per[str(aid)] = {"category": str(g["category"].iloc[0]), "tracked_boxes": len(g)}
            per[str(aid)].update({src: _stats(g, src) for src in SOURCES})
    return overall, per


# --------------------------------------------------------------------------- crash
def resolve_participants(
    label: CrashLabel, scenario: Scenario, tracks: pd.DataFrame
) -> tuple[list[int | None], list[str]]:
    """Scenario ids of the label's participants (the ego is 0; a box -> its best-overlapping track,
    when that track is an agent of the scenario); None where unresolved, with a note why."""
    ids: list[int | None] = []
    notes: list[str] = []
    agent_ids = {a.id for a in scenario.agents}
    for p in label.participants:
        if p.ego:
            ids.append(scenario.ego.id)
            continue
        assert p.box is not None and label.contact_frame is not None
        best: tuple[float, int] | None = None
        for slack in range(LABEL_FRAME_SLACK + 1):
            near = tracks[(tracks["frame"] - label.contact_frame).abs() == slack]
            if len(near):
                iou = iou_matrix(np.array(p.box), near[["x1", "y1", "x2", "y2"]].to_numpy(float))[0]
                j = int(iou.argmax())
                if iou[j] >= LABEL_TRACK_IOU:
                    best = (float(iou[j]), int(near["track_id"].iloc[j]))
                    break
        if best is None:
            ids.append(None)
            notes.append(f"labelled {p.describe()} is not tracked near frame {label.contact_frame}")
        elif best[1] not in agent_ids:
            ids.append(None)
            notes.append(f"labelled {p.describe()} is track {best[1]}, which is not an agent of the scenario")
        elif best[1] in ids:
            ids.append(None)
            notes.append(f"labelled {p.describe()} is track {best[1]}, the same track as the other participant")
        else:
            ids.append(best[1])
    return ids, notes


def _contact(scenario: Scenario, c: dict[str, Any]) -> dict[str, Any]:
    t = float(c["time"])
    return {
        "participants": sorted(int(v) for v in c["vehicles"]),
        "scenario_time_s": round(t, 4),
        "video_time_s": round(float(scenario.video_time(t)), 4),
        "video_frame": scenario.video_frame(t),
        "relative_speed_mps": c.get("relative_speed"),
        "point": c.get("point"),
    }


def labelled_contact_time(scenario: Scenario, label: CrashLabel) -> float:
    """Video time (s) of the label's contact frame as the scenario times its frames: the frame's own where the
    video's rate varies (``source.frame_times``), else ``contact_frame / fps`` at the scenario's frame rate (a video
    re-timed by its clock runs at another rate than the label's file; 0 without a contact frame)."""
    if label.contact_frame is None:
        return 0.0
    return float(scenario.video_time(scenario.frame_time(label.contact_frame)))


def compare_crash(
    scenario: Scenario, sim: Any | None, label: CrashLabel | None, tracks: pd.DataFrame
) -> tuple[dict[str, Any], list[str]]:
    """The replay's first contact against the label (see the module docstring)."""
    contacts = [_contact(scenario, c) for c in (sim.collisions if sim is not None else [])]
    first = contacts[0] if contacts else None
    col = scenario.collision
    out: dict[str, Any] = {
        "first_contact": first,
        "contacts": len(contacts),
        "scenario_collision": None
        if col is None
        else {
            "participants": sorted(col.participants),
            "video_time_s": round(float(scenario.video_time(col.time_s)), 4),
            "source": col.source,
        },
        "labelled": label is not None,
    }
    notes: list[str] = []
    if label is None:
        out["video_has_crash"] = col is not None
        out["video_has_crash_source"] = "scenario collision (no label)"
        return out, notes
    out["video_has_crash"] = label.crash
    out["video_has_crash_source"] = "label"
    out["label"] = {
        "contact_frame": label.contact_frame,
        "video_time_s": label.contact_video_time,
        "participants": [p.describe() for p in label.participants],
        "description": label.description,
    }
    if not label.crash:
        out.update(reproduced=first is None, contacts_before_crash=len(contacts), same_pair=None, dt_s=None)
        return out, notes
    if label.contact_frame is None:
        notes.append("the label has a crash but no contact frame (not visible to the labeller)")
        out.update(reproduced=None, contacts_before_crash=None, same_pair=None, dt_s=None)
        return out, notes
    ids, notes = resolve_participants(label, scenario, tracks)
    t_label = labelled_contact_time(scenario, label)
    out["label"]["video_time_s"] = t_label
    out["label"]["scenario_ids"] = ids
    pair = sorted(i for i in ids if i is not None) if None not in ids else None
    same = bool(first is not None and pair is not None and first["participants"] == pair)
    dt = None if first is None else round(first["video_time_s"] - t_label, 4)
    out["same_pair"] = same
    out["dt_s"] = dt
    out["relative_speed_mps"] = first["relative_speed_mps"] if first is not None else None
    out["reproduced"] = bool(same and dt is not None and abs(dt) <= CRASH_DT_S)
    out["contacts_before_crash"] = sum(c["video_time_s"] < t_label - CRASH_DT_S for c in contacts)
    labelled_contact = next((c for c in contacts if pair is not None and c["participants"] == pair), None)
    out["labelled_pair_contact"] = labelled_contact
    if col is not None and pair is not None:
        out["scenario_collision"]["same_pair"] = sorted(col.participants) == pair
        out["scenario_collision"]["dt_s"] = round(out["scenario_collision"]["video_time_s"] - t_label, 4)
    return out, notes


# --------------------------------------------------------------------------- entry points
def evaluate_fidelity(
    scenario: Scenario, tracks: pd.DataFrame, sim: Any | None = None, label: CrashLabel | None = None, name: str = ""
) -> FidelityResult:
    """Reprojection and crash fidelity of ``scenario`` (and its replay ``sim``, a SimResult) against
    the video's ``tracks`` and an optional crash ``label``."""
    every = reprojection_pairs(scenario, tracks, sim, anchored=False)
    pairs = every[every["anchored"]].reset_index(drop=True) if len(every) else every
    overall, per = summarise_reprojection(pairs)
    track_ids = set(int(v) for v in tracks["track_id"].unique()) if len(tracks) else set()
    agent_ids = {a.id for a in scenario.agents}
    overall["tracks"] = len(track_ids)
    overall["tracks_in_scenario"] = len(track_ids & agent_ids)
    overall["tracked_boxes_total"] = len(tracks)
    overall["coasting_boxes_excluded"] = len(tracks) - len(detection_anchored(tracks))
    overall["all_tracked_boxes"] = {src: _stats(every, src)["mean_iou"] for src in SOURCES}
    crash, notes = compare_crash(scenario, sim, label, tracks)
    mapping = {
        "fps": scenario.source.fps,
        "time_offset_s": scenario.source.time_offset_s,
        "rule": "scenario time = frame / fps + time_offset_s (Scenario.frame_time / video_time)"
        if scenario.source.frame_times is None
        else "scenario time = source.frame_times[frame] + time_offset_s (a variable frame rate; Scenario.frame_time)",
    }
    return FidelityResult(name or scenario.name, mapping, pairs, overall, per, crash, notes, plausibility(scenario))


def fidelity_json(result: FidelityResult | dict[str, Any]) -> str:
    """A result (or its dict, possibly extended) as one JSON document (NaN -> null)."""
    data = result.to_dict() if isinstance(result, FidelityResult) else result
    return json.dumps(_finite(data), indent=1) + "\n"


def _finite(o: Any) -> Any:
    if isinstance(o, dict):
        return {k: _finite(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [_finite(v) for v in o]
    if isinstance(o, np.generic):
        o = o.item()
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return o
