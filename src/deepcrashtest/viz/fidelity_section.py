"""The report's "Reconstruction fidelity" section, from a fidelity result (``fidelity.json`` or a FidelityResult)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from deepcrashtest.errors import UserError
from deepcrashtest.fileio import read_json, require_file
from deepcrashtest.viz.report import Section, esc, fmt, table


def load_fidelity(path: str | Path) -> dict[str, Any]:
    """A ``fidelity.json`` written by ``deepcrashtest evaluate fidelity``."""
    p = require_file(path, "fidelity result")
    data = read_json(p)
    if not isinstance(data, dict) or "reprojection" not in data or "crash" not in data:
        raise UserError(f"{p}: not a fidelity result (no reprojection/crash)")
    return data


def _verdict(crash: dict[str, Any]) -> str:
    if crash.get("reproduced") is True:
        return "the replay reproduces the labelled crash"
    if crash.get("reproduced") is False:
        return "the replay does NOT reproduce the labelled crash"
    first = crash.get("first_contact")
    return "no label; the replay has no contact" if first is None else "no label; see the replay's first contact"


def fidelity_section(result: Any) -> Section:
    """HTML section: reprojection IoU (processed scenario, replay), crash comparison, per-agent table.

    ``result``: a :class:`~deepcrashtest.eval.fidelity.FidelityResult` or its dict (``fidelity.json``).
    """
    data = result.to_dict() if hasattr(result, "to_dict") else result
    rep, crash, mapping = data["reprojection"], data["crash"], data["time_mapping"]
    rows = [("time mapping", f"{mapping['rule']}; offset {fmt(mapping['time_offset_s'], 4)} s")]
    rows.append(("tracked boxes of scenario agents", rep["tracked_boxes"]))
    rows.append(("tracks in the scenario", f"{rep.get('tracks_in_scenario')} of {rep.get('tracks')}"))
    for src in ("processed", "simulated"):
        s = rep[src]
        rows.append(
            (
                f"{src}: mean IoU / IoU>=0.5 / median centre error (px) / coverage",
                f"{fmt(s['mean_iou'])} / {fmt(s['share_iou_ge_0_5'])} / {fmt(s['median_centre_px'])} / "
                f"{fmt(s['coverage'])}",
            )
        )
        rows.append(
            (
                f"{src}: median offset right / down (px), width / height ratio",
                f"{fmt(s.get('median_du_px'))} / {fmt(s.get('median_dv_px'))}, "
                f"{fmt(s.get('median_width_ratio'))} / {fmt(s.get('median_height_ratio'))}",
            )
        )
    first = crash.get("first_contact")
    rows.append(
        (
            "replay's first contact",
            "none"
            if first is None
            else f"{'-'.join(str(v) for v in first['participants'])} at video {fmt(first['video_time_s'])} s, "
            f"{fmt(first['relative_speed_mps'])} m/s",
        )
    )
    label = crash.get("label")
    if label is not None:
        rows += [
            ("labelled crash", f"{label['description']} (frame {fmt(label['contact_frame'])})"),
            ("same participants", crash.get("same_pair")),
            ("time error (s, video)", crash.get("dt_s")),
            ("contacts before the labelled crash", crash.get("contacts_before_crash")),
        ]
    else:
        rows.append(
            ("video has a crash", f"{fmt(crash.get('video_has_crash'))} ({crash.get('video_has_crash_source')})")
        )
    agents = "".join(
        f"<tr><td>{esc(aid)}</td><td>{esc(a['category'])}</td><td>{esc(a['tracked_boxes'])}</td>"
        f"<td>{esc(fmt(a['processed']['mean_iou']))}</td><td>{esc(fmt(a['simulated']['mean_iou']))}</td></tr>"
        for aid, a in sorted(data.get("per_agent", {}).items(), key=lambda kv: int(kv[0]))
    )
    head = "<tr><th>agent</th><th>category</th><th>boxes</th><th>IoU processed</th><th>IoU simulated</th></tr>"
    notes = "".join(f"<li>{esc(n)}</li>" for n in data.get("notes", []))
    body = (
        f'<p class="verdict">{esc(_verdict(crash))}</p>'
        + table(rows)
        + (f'<table class="kv">{head}{agents}</table>' if agents else "")
        + (f"<ul>{notes}</ul>" if notes else "")
    )
    return Section("Reconstruction fidelity", body)
