"""Robustness of the video pipeline on realistic variants of the crash clips (issue 16).

Makes variants of shared crash clips into ``$ROBUST_DIR/videos`` (default ``/tmp/robust``) (never into the repository):
downscaled 640x360, upscaled 1920x1080, resampled to 15/25/30 fps, re-encoded at crf 35, letterboxed,
pillarboxed, filmed off a screen by a phone (perspective, blur, gamma, moire, noise), a portrait 9:16
crop, a burned-in text overlay, a 2-shot compilation, 10 frames around the crash, a frozen stretch, in low light (dark,
noisy), shaken (motion blur along a random direction per frame);
and a label file ``/tmp/robust/labels.json`` with the clips' labels mapped (boxes, frames rescaled).
Then ``run`` extracts each with the CLI and evaluates the fidelity as ``bench/fidelity_crashes.py``.

Usage::

    python bench/robust_variants.py make '{"ccd_000053": ["down", "up", "fps15", "fps25", "fps30", "crf35",
        "letterbox", "pillarbox", "phone", "portrait", "text", "compil", "short", "frozen", "dark", "shake"]}'
    TAG=r1 python bench/robust_variants.py run ccd_000053_down640 ccd_000053_fps30 ...
    TAG=r1 python bench/robust_variants.py score ccd_000053_compil ...   # score out_r1 again, no extract
    TAG=r1 NEW=r2 python bench/robust_variants.py restage [--redetect] ccd_000053_phone ...  # stage 2 again

``restage`` copies ``out_TAG/NAME`` to ``out_NEW/NAME`` and reruns this checkout's stage 2 on its
``scenario_raw.json`` (``--redetect``: the automatic crash detection on its ``tracks.csv`` first, the camera's
motion cached in ``$ROBUST_DIR/motion``), then scores it (rows in ``results_NEW.jsonl``).

``ROBUST_DIR`` (default ``/tmp/robust``) is the folder of the videos, labels and outputs (one per user).
A compilation's extraction (``shot_NN`` folders) is scored on the shot whose tracks cover the contact.

Each ``run`` row (JSON lines, also appended to ``/tmp/robust/results_TAG.jsonl``): exit code, whether
stderr held a traceback, reproduced / same pair / dt (s) / IoU processed and replay.
"""

import json
import os
import sys
from pathlib import Path

import av
import cv2
import numpy as np

DATA = Path("/work/shared/data")
ROOT = Path(os.environ.get("ROBUST_DIR", "/tmp/robust"))  # own folder per user of the script
OUT = ROOT / "videos"
OUT.mkdir(parents=True, exist_ok=True)
LAB = {}
for f in ("dad_crashes.json", "ccd_crashes.json"):
    LAB.update(json.load(open(Path(__file__).resolve().parent / "labels" / f))["clips"])


def read(name):
    c = av.open(str(DATA / LAB[name]["video"]))
    fr = [f.to_ndarray(format="bgr24") for f in c.decode(video=0)]
    c.close()
    return fr


def write(path, frames, fps, crf=20):
    c = av.open(str(path), "w")
    h, w = frames[0].shape[:2]
    s = c.add_stream("libx264", rate=int(round(fps)) if float(fps).is_integer() else fps)
    s.width, s.height, s.pix_fmt = w, h, "yuv420p"
    s.options = {"crf": str(crf), "preset": "veryfast"}
    for f in frames:
        for p in s.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(f), format="bgr24")):
            c.mux(p)
    for p in s.encode():
        c.mux(p)
    c.close()


def variant(vname, base, frames, fps, box_map=lambda b: b, frame_map=lambda k: k, crf=20):
    write(OUT / f"{vname}.mp4", frames, fps, crf)
    lab = dict(LAB[base])
    lab["video"] = str(OUT / f"{vname}.mp4")
    lab["fps"] = float(fps)
    if lab.get("contact_frame") is not None:
        lab["contact_frame"] = int(frame_map(lab["contact_frame"]))
    if lab.get("first_accident_frame") is not None:
        lab["first_accident_frame"] = int(frame_map(lab["first_accident_frame"]))
    lab["participants"] = [
        dict(p, box=[float(v) for v in box_map(p["box"])]) if "box" in p else p for p in lab["participants"]
    ]
    cut = [
        p["box"]
        for p in lab["participants"]
        if "box" in p and not (p["box"][2] > p["box"][0] and p["box"][3] > p["box"][1])
    ]
    if cut:  # a labelled road user outside the variant's picture (dad_000478's pair left of a portrait crop)
        print(vname, "not labelled: a crash participant is outside its picture", cut, flush=True)
        return
    LAB_OUT[vname] = lab
    print(vname, len(frames), frames[0].shape, fps, lab["contact_frame"], flush=True)


def scale(b, s, dx=0, dy=0):
    return [b[0] * s + dx, b[1] * s + dy, b[2] * s + dx, b[3] * s + dy]


LAB_OUT = {}


def make(base, which):
    fr = read(base)
    fps = LAB[base]["fps"]
    H, W = fr[0].shape[:2]
    n = len(fr)
    for key, suffix, size, interp, factor in (
        ("down", "down640", (640, 360), cv2.INTER_AREA, 0.5),
        ("up", "up1080", (1920, 1080), cv2.INTER_CUBIC, 1.5),
    ):
        if key in which:
            frames = [cv2.resize(f, size, interpolation=interp) for f in fr]
            variant(f"{base}_{suffix}", base, frames, fps, lambda b, k=factor: scale(b, k))
    for r in (15, 25, 30):
        if f"fps{r}" in which:
            m = int(np.floor((n - 1) / fps * r)) + 1
            idx = [min(n - 1, int(round(j * fps / r))) for j in range(m)]
            variant(f"{base}_fps{r}", base, [fr[i] for i in idx], r, frame_map=lambda k, r=r: round(k * r / fps))
    if "crf35" in which:
        variant(f"{base}_crf35", base, fr, fps, crf=35)
    if "letterbox" in which:  # 16:9 content in a 4:3 frame (bars top/bottom)
        pad = (W * 3 // 4 - H) // 2
        variant(
            f"{base}_letterbox",
            base,
            [cv2.copyMakeBorder(f, pad, pad, 0, 0, cv2.BORDER_CONSTANT) for f in fr],
            fps,
            lambda b: scale(b, 1, 0, pad),
        )
    if "pillarbox" in which:  # content shrunk into a 16:9 frame with side bars (and small top/bottom bars)
        s = 0.75
        w2, h2 = int(W * s) // 2 * 2, int(H * s) // 2 * 2
        dx, _dy = (W - w2) // 2, 0

        def pb(f):
            g = np.zeros((h2, W, 3), np.uint8)
            g[:, dx : dx + w2] = cv2.resize(f, (w2, h2), interpolation=cv2.INTER_AREA)
            return g

        variant(f"{base}_pillarbox", base, [pb(f) for f in fr], fps, lambda b: scale(b, w2 / W, dx, 0))
    if "phone" in which:  # screen filmed by a phone: zoomed, slightly rotated, perspective, blur, gamma, noise, moire
        rng = np.random.default_rng(0)
        src = np.float32([[0, 0], [W, 0], [W, H], [0, H]])
        dst = np.float32([[-60, -30], [W + 40, -50], [W + 70, H + 40], [-50, H + 55]])
        M = cv2.getPerspectiveTransform(src, dst)
        yy, xx = np.mgrid[0:H, 0:W]
        moire = (6 * np.sin(xx * 0.9 + yy * 0.35)).astype(np.float32)[..., None]

        def ph(f, i):
            g = cv2.warpPerspective(f, M, (W, H))
            g = cv2.GaussianBlur(g, (5, 5), 1.2)
            g = 255 * (g / 255.0) ** 0.8 * 0.85 + 20 + moire + rng.normal(0, 4, g.shape)
            return np.clip(g, 0, 255).astype(np.uint8)

        def bm(b):
            p = cv2.perspectiveTransform(np.float32([[[b[0], b[1]], [b[2], b[1]], [b[2], b[3]], [b[0], b[3]]]]), M)[0]
            return [max(0, p[:, 0].min()), max(0, p[:, 1].min()), min(W, p[:, 0].max()), min(H, p[:, 1].max())]

        variant(f"{base}_phone", base, [ph(f, i) for i, f in enumerate(fr)], fps, bm, crf=28)
    if "portrait" in which:  # central 9:16 crop
        w2 = int(H * 9 / 16) // 2 * 2
        x0 = (W - w2) // 2
        variant(
            f"{base}_portrait",
            base,
            [np.ascontiguousarray(f[:, x0 : x0 + w2]) for f in fr],
            fps,
            lambda b: [max(0, b[0] - x0), b[1], min(w2, b[2] - x0), b[3]],
        )
    if "text" in which:

        def tx(f, i):
            g = f.copy()
            cv2.rectangle(g, (0, H - 90), (W, H), (0, 0, 0), -1)
            cv2.putText(
                g, "SHOCKING CRASH CAUGHT ON DASHCAM!!", (30, H - 35), cv2.FONT_HERSHEY_DUPLEX, 1.6, (0, 255, 255), 3
            )
            cv2.putText(
                g,
                f"2026/03/0{i % 9 + 1} 12:3{i % 10}:0{i % 7}  {80 + i % 13} KM/H",
                (W - 560, 50),
                cv2.FONT_HERSHEY_SIMPLEX,
                1.1,
                (255, 255, 255),
                2,
            )
            cv2.putText(g, "@crashchannel", (W // 2 - 150, H // 2), cv2.FONT_HERSHEY_SIMPLEX, 1.5, (255, 255, 255), 2)
            return g

        variant(f"{base}_text", base, [tx(f, i) for i, f in enumerate(fr)], fps)
    if "dark" in which:  # low light (dusk): the picture darkened (gamma 2.2, x 0.6) under high-ISO sensor noise
        rng = np.random.default_rng(1)

        def nt(f):
            g = 255 * 0.6 * (f / 255.0) ** 2.2 + rng.normal(0, 5, f.shape)
            return np.clip(g, 0, 255).astype(np.uint8)

        variant(f"{base}_dark", base, [nt(f) for f in fr], fps, crf=26)
    if "shake" in which:  # a loose mount: each frame blurred along a random direction (7-15 px motion blur)
        rng = np.random.default_rng(2)

        def sh(f):
            n = int(rng.integers(7, 16))
            k = np.zeros((n, n), np.float32)
            k[n // 2, :] = 1.0 / n
            rot = cv2.getRotationMatrix2D(((n - 1) / 2, (n - 1) / 2), float(rng.uniform(0, 180)), 1.0)
            k = cv2.warpAffine(k, rot, (n, n))
            return cv2.filter2D(f, -1, k / max(float(k.sum()), 1e-6))

        variant(f"{base}_shake", base, [sh(f) for f in fr], fps)
    if "compil" in which:  # first 30 frames of another clip, a hard cut, then this clip
        other = {"ccd": "ccd_000330", "dad": "dad_000528"}[base[:3]]
        other = "ccd_000053" if other == base else other
        o = [cv2.resize(f, (W, H)) for f in read(other)[:30]]
        variant(f"{base}_compil", base, o + fr, fps, frame_map=lambda k: k + len(o))
    if "short" in which:
        c = LAB[base]["contact_frame"]
        s0 = max(0, c - 6)
        variant(f"{base}_short10", base, fr[s0 : s0 + 10], fps, frame_map=lambda k: k - s0)
    if "frozen" in which:
        c = LAB[base]["contact_frame"]
        k0 = c - 15 if fps < 15 else c - 30
        d = 8 if fps < 15 else 15
        frz = fr[:k0] + [fr[k0]] * d + fr[k0:]
        variant(f"{base}_frozen", base, frz, fps, frame_map=lambda k: k + d)


def make_main(argv):
    plan = json.loads(argv[0])
    for base, which in plan.items():
        make(base, which)
    p = ROOT / "labels.json"
    old = json.load(open(p))["clips"] if p.exists() else {}
    old.update(LAB_OUT)
    p.write_text(json.dumps({"format": "deepcrashtest-crash-labels", "version": 1, "clips": old}, indent=1))


def _crash_shot(out, name):
    """The extraction folder to score: ``out`` itself, or for a compilation the shot folder
    (``shot_NN``) whose tracks cover the labelled contact frame (else its last shot); None if none."""
    if (out / "scenario.json").is_file():
        return out
    shots = sorted(p for p in out.glob("shot_*") if (p / "scenario.json").is_file())
    if not shots:
        return None
    labels = json.load(open(ROOT / "labels.json"))["clips"]
    contact = labels.get(name, {}).get("contact_frame")
    for p in shots:
        lines = (p / "tracks.csv").read_text().splitlines()[1:]
        frames = [int(float(ln.split(",")[0])) for ln in lines if ln]
        if contact is not None and frames and min(frames) <= contact <= max(frames):
            return p
    return shots[-1]


def run_main(names, extract=True):
    """Extract each variant with the CLI (``extract=False``: score the extraction already in ``out_TAG``)
    and score its fidelity; one JSON row each."""
    import subprocess
    import time

    wt = Path(__file__).resolve().parents[1]
    tag = os.environ.get("TAG", "r1")
    res_path = ROOT / f"results_{tag}.jsonl"
    for name in names:
        video = OUT / f"{name}.mp4"
        out = ROOT / f"out_{tag}" / name
        row = {"variant": name}
        if extract:
            t0 = time.time()
            cmd = [sys.executable, "-m", "deepcrashtest.cli", "extract", str(video), "-o", str(out), "--force"]
            env = dict(os.environ, PYTHONPATH=os.environ.get("SRC", str(wt / "src")))  # SRC: another checkout's
            p = subprocess.run(["nice", "-n", "10", *cmd], env=env, capture_output=True, text=True)
            row.update(
                rc=p.returncode,
                extract_s=round(time.time() - t0, 1),
                traceback="Traceback" in p.stderr,
                stderr_tail=p.stderr.strip().splitlines()[-3:],
            )
        shot = _crash_shot(out, name)
        if shot is not None:
            row["shot"] = shot.name if shot != out else None
            row.update(_score(shot, video, name))
        print(json.dumps(row), flush=True)
        with open(res_path, "a") as f:
            f.write(json.dumps(row) + "\n")


def restage_main(names, redetect=False):
    """Stage 2 (and with ``redetect`` the crash detection) of this checkout on copies of ``out_TAG``'s
    extractions in ``out_NEW``; one scored JSON row each (``restage`` in the module docstring)."""
    import shutil

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from crash_detect_bench import global_motion

    from deepcrashtest.eval.fidelity import read_tracks
    from deepcrashtest.pipeline.crash import crash_for_raw
    from deepcrashtest.scenario import Scenario
    from deepcrashtest.trajectory.pipeline import process_scenario

    tag, new = os.environ.get("TAG", "r1"), os.environ["NEW"]
    for name in names:
        src, dst = ROOT / f"out_{tag}" / name, ROOT / f"out_{new}" / name
        shutil.rmtree(dst, ignore_errors=True)
        shutil.copytree(src, dst)
        shot = _crash_shot(dst, name)
        row = {"variant": name, "from": tag, "redetect": redetect}
        if shot is not None:
            raw = Scenario.load(shot / "scenario_raw.json")
            if redetect:
                tracks = read_tracks(shot / "tracks.csv")
                fr, sh = global_motion(OUT / f"{name}.mp4", ROOT / "motion", None)
                m = (fr >= tracks["frame"].min()) & (fr <= tracks["frame"].max())
                sh = sh[m].copy()
                sh[0] = 0.0  # a shot's own pass starts its motion afresh (no shift across the cut)
                from deepcrashtest.video.bars import video_picture_area

                raw, rec = crash_for_raw(raw, tracks, (fr[m], sh), picture=video_picture_area(OUT / f"{name}.mp4"))
                raw.save(shot / "scenario_raw.json", force=True)
                row["detected"] = [rec.get("frame"), rec.get("pair"), rec.get("confidence")]
            process_scenario(raw).save(shot / "scenario.json", force=True)
            row["shot"] = shot.name if shot != dst else None
            row.update(_score(shot, OUT / f"{name}.mp4", name))
        print(json.dumps(row), flush=True)
        with open(ROOT / f"results_{new}.jsonl", "a") as f:
            f.write(json.dumps(row) + "\n")


def _score(shot, video, name):
    """The fidelity row of one extraction folder (``scenario.json``, ``tracks.csv``) against the labels."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
    from deepcrashtest.pipeline.fidelity import run_fidelity

    _, s = run_fidelity(
        shot / "scenario.json",
        shot / "fidelity",
        video=video,
        tracks=shot / "tracks.csv",
        labels=str(ROOT / "labels.json"),
        clip=name,
        make_video=False,
        force=True,
    )
    c, rep = s["crash"], s["reprojection"]
    fc = c["first_contact"]
    return dict(
        reproduced=c.get("reproduced"),
        same_pair=c.get("same_pair"),
        dt=c.get("dt_s"),
        first=None if fc is None else fc["participants"],
        label_ids=c.get("label", {}).get("scenario_ids"),
        iou_p=rep["processed"]["mean_iou"],
        iou_s=rep["simulated"]["mean_iou"],
        notes=s["notes"],
    )


if __name__ == "__main__":
    if len(sys.argv) < 3 or sys.argv[1] not in ("make", "run", "score", "restage"):
        sys.exit(__doc__)
    cmd, args = sys.argv[1], sys.argv[2:]
    if cmd == "make":
        make_main(args)
    elif cmd == "restage":
        restage_main([a for a in args if a != "--redetect"], redetect="--redetect" in args)
    else:
        run_main(args, extract=cmd == "run")
