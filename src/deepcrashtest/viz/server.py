"""``deepcrashtest view``: a local web app to look at a Scenario, fix its waypoints and simulate it.

The server only ever touches the scenario's own folder: it reads the scenario and the
extraction's ``annotated.mp4`` beside it, and writes new scenario files there ("Save as").
Every request body is JSON, decoded without NaN/Infinity and validated with the Scenario model;
errors are ``{"error": "..."}`` with a 4xx status. Edits themselves are computed here
(:mod:`deepcrashtest.viz.edit`); the page keeps the undo/redo stack of whole scenarios.

Endpoints: ``GET /`` (the page), ``GET /static/<file>``, ``GET /api/scenario``,
``GET /api/frame?t=SECONDS`` or ``?frame=N`` (JPEG), ``POST /api/edit``, ``POST /api/simulate``,
``POST /api/save``.

Time: the page's slider is scenario time. The one mapping to the video is the Scenario's own
(``source.time_offset_s``; :meth:`Scenario.video_frame`): video time = scenario time - offset,
frame = floor(video time x fps), none before frame 0 or from ``frame_count`` on. ``/api/scenario``
sends the three numbers (``time``) and the page maps with the same formula (``viewer.js``
``videoFrame``); ``/api/frame?t=`` maps here and answers 404 with ``state`` "before"/"after" outside
the video, never a frozen frame.
"""

from __future__ import annotations

import json
import math
import socket
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse, JSONResponse, Response
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.middleware.trustedhost import TrustedHostMiddleware

from deepcrashtest.errors import UserError
from deepcrashtest.fileio import atomic_write_text
from deepcrashtest.geometry.road import lane_lines
from deepcrashtest.scenario import Scenario, _reject_constant
from deepcrashtest.viz import style
from deepcrashtest.viz.edit import DEFAULT_FALLOFF_S, apply_edit
from deepcrashtest.viz.projection import projected_frames, scenario_poses, sim_poses
from deepcrashtest.viz.video_frames import VideoFrames, jpeg_bytes

VIDEO_NAME = "annotated.mp4"
STATIC_FILES = {"viewer.js": "text/javascript", "viewer.css": "text/css"}
LOOPBACK_HOSTS = ["127.0.0.1", "localhost", "::1", "[::1]"]
MAX_BODY_BYTES = 64 * 1024 * 1024
#: At most this many time samples of a simulation are sent to the page.
MAX_SIM_SAMPLES = 800


class ApiError(Exception):
    """An error answered as ``{"error": message}`` with ``status``."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status
        self.message = message


def inside(root: Path, path: Path) -> bool:
    """True when ``path`` (symlinks resolved) lies in the folder ``root``."""
    return path.resolve().is_relative_to(root.resolve())


def safe_target(root: Path, name: Any) -> Path:
    """The path for a new scenario file called ``name`` in ``root``, or ApiError(400).

    Only a plain file name ending in ``.json`` is accepted: no folders, no absolute paths,
    no hidden names, and no symlink (which could point out of the folder).
    """
    if not isinstance(name, str) or not name.strip():
        raise ApiError(400, "filename must be a non-empty string")
    if len(name) > 200 or any(c in name for c in "/\\\0:") or name in (".", ".."):
        raise ApiError(400, f"filename {name!r} must be a plain file name (no folders, no path)")
    if Path(name).is_absolute() or name.startswith("."):
        raise ApiError(400, f"filename {name!r} must not be absolute or hidden")
    if not name.endswith(".json"):
        raise ApiError(400, f"filename {name!r} must end with .json")
    target = root / name
    if target.is_symlink():
        raise ApiError(400, f"{name}: is a symlink; refusing to write through it")
    if not inside(root, target.parent) or target.resolve().parent != root.resolve():
        raise ApiError(400, f"{name}: outside the scenario's folder")
    if target.exists() and not target.is_file():
        raise ApiError(400, f"{name}: exists and is not a regular file")
    return target


def time_mapping(scenario: Scenario, video: VideoFrames | None) -> dict[str, Any]:
    """What the page needs to map scenario time to video frames exactly as :meth:`Scenario.video_frame` does.

    ``frame_count`` is the smaller of the scenario's and the annotated video's (a frame the file lacks
    is "after the video"); ``video_start_s``/``video_end_s`` are the scenario times of the first frame
    and of the end of the last one.
    """
    src = scenario.source
    count = src.frame_count
    if video is not None and video.frame_count > 0:
        count = min(count, video.frame_count) if count > 0 else video.frame_count
    return {
        "offset_s": src.time_offset_s,
        "fps": src.fps,
        "frame_count": count,
        "video_start_s": scenario.frame_time(0),
        "video_end_s": scenario.frame_time(count),
        "frame_times": src.frame_times,
        "formula": "frame = floor((t - offset_s) * fps + 1e-6), or the last frame whose frame_times entry is not "
        "after t - offset_s where the rate varies; none if < 0 or >= frame_count",
    }


def mapped_frame(scenario: Scenario, t: float, frame_count: int) -> tuple[int | None, str]:
    """Video frame at scenario time ``t`` (:meth:`Scenario.video_frame`) and "before"/"inside"/"after"."""
    f = scenario.video_frame(t)
    if f is None:
        return None, "before" if scenario.video_time(t) < 0 else "after"
    if frame_count > 0 and f >= frame_count:
        return None, "after"
    return f, "inside"


def finite_or_none(value: Any) -> Any:
    """JSON-safe copy: numpy scalars to Python, non-finite floats to None (recursively)."""
    if isinstance(value, dict):
        return {str(k): finite_or_none(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite_or_none(v) for v in value]
    if isinstance(value, np.ndarray):
        return finite_or_none(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def sim_payload(res: Any, max_samples: int = MAX_SIM_SAMPLES) -> dict[str, Any]:
    """The page's view of a SimResult: metrics, and states at most ``max_samples`` times."""
    times = np.asarray(res.times, float)
    step = max(1, math.ceil(len(times) / max_samples))
    keep = np.arange(0, len(times), step)
    if len(times) and keep[-1] != len(times) - 1:
        keep = np.append(keep, len(times) - 1)
    states = np.asarray(res.states, float)[keep]
    present = np.asarray(res.present, bool)[keep]
    states = np.where(present[..., None], states, np.nan)
    return {
        "metrics": finite_or_none(dict(res.metrics)),
        "collisions": finite_or_none(list(getattr(res, "collisions", []) or [])),
        "times": finite_or_none(times[keep]),
        "vehicle_ids": [int(i) for i in res.vehicle_ids],
        "states": finite_or_none(np.round(states, 4)),
        "present": present.tolist(),
    }


async def json_body(request: Request) -> dict[str, Any]:
    """The request's JSON object (Content-Type application/json; no NaN/Infinity), or ApiError."""
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype != "application/json":
        raise ApiError(415, "request body must be JSON (Content-Type: application/json)")
    raw = await request.body()
    if len(raw) > MAX_BODY_BYTES:
        raise ApiError(413, f"request body is larger than {MAX_BODY_BYTES // (1024 * 1024)} MiB")
    try:
        data = json.loads(raw, parse_constant=_reject_constant)
    except json.JSONDecodeError as exc:
        raise ApiError(400, f"invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise ApiError(400, f"invalid JSON: {exc}") from None
    if not isinstance(data, dict):
        raise ApiError(400, f"request body must be a JSON object, got {type(data).__name__}")
    return data


def body_scenario(body: dict[str, Any]) -> Scenario:
    """Validate ``body["scenario"]`` with the Scenario model (ApiError 422 naming the field)."""
    if "scenario" not in body:
        raise ApiError(422, "request body has no 'scenario'")
    try:
        return Scenario.from_dict(body["scenario"], origin="scenario")
    except UserError as exc:
        raise ApiError(422, str(exc)) from None


def _static_text(name: str) -> str:
    return (resources.files("deepcrashtest.viz") / "static" / name).read_text(encoding="utf-8")


def create_app(scenario_path: str | Path, allowed_hosts: list[str] | None = None) -> FastAPI:
    """The viewer app for one scenario file; it reads and writes only in that file's folder.

    ``allowed_hosts``: Host headers answered (default: loopback names only, which also stops
    DNS-rebinding pages from talking to the server).
    """
    original = Path(scenario_path)
    scenario = Scenario.load(original)
    root = original.resolve().parent
    video: VideoFrames | None = None
    video_note = "no annotated.mp4 beside the scenario"
    video_path = root / VIDEO_NAME
    if video_path.exists():
        if inside(root, video_path):
            video = VideoFrames(video_path)
            video_note = ""
        else:
            video_note = f"{VIDEO_NAME} is a symlink out of the scenario's folder: ignored"

    app = FastAPI(title="DeepCrashTest viewer", docs_url=None, redoc_url=None, openapi_url=None)
    app.add_middleware(TrustedHostMiddleware, allowed_hosts=allowed_hosts or LOOPBACK_HOSTS)

    @app.exception_handler(ApiError)
    async def _api_error(_: Request, exc: ApiError) -> JSONResponse:
        return JSONResponse({"error": exc.message}, status_code=exc.status)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(_: Request, exc: StarletteHTTPException) -> JSONResponse:
        return JSONResponse({"error": str(exc.detail)}, status_code=exc.status_code)

    @app.exception_handler(RequestValidationError)
    async def _validation_error(_: Request, exc: RequestValidationError) -> JSONResponse:
        errs = exc.errors()
        msg = "; ".join(f"{'.'.join(str(p) for p in e['loc'])}: {e['msg']}" for e in errs[:3])
        return JSONResponse({"error": msg or "invalid request"}, status_code=422)

    @app.get("/", response_class=HTMLResponse)
    def index() -> HTMLResponse:
        return HTMLResponse(_static_text("index.html"), headers={"Cache-Control": "no-store"})

    @app.get("/favicon.ico")
    def favicon() -> Response:
        return Response(status_code=204)

    @app.get("/static/{name}")
    def static(name: str) -> Response:
        if name not in STATIC_FILES:
            raise ApiError(404, f"no static file {name!r}")
        return Response(_static_text(name), media_type=STATIC_FILES[name], headers={"Cache-Control": "no-store"})

    @app.get("/api/scenario")
    def get_scenario() -> JSONResponse:
        return JSONResponse(
            {
                "file": original.name,
                "scenario": scenario.model_dump(mode="json"),
                "road": lane_lines(scenario.road),
                "video": None if video is None else video.info(),
                "video_note": video_note,
                "time": time_mapping(scenario, video),
                "style": style.page_style(),
                "default_falloff_s": DEFAULT_FALLOFF_S,
            }
        )

    @app.get("/api/frame")
    def frame(t: float | None = None, frame: int | None = None) -> Response:
        if video is None:
            raise ApiError(404, video_note)
        count = int(time_mapping(scenario, video)["frame_count"])
        if frame is None:
            if t is None or not math.isfinite(t):
                raise ApiError(422, f"give t, a finite number of seconds of scenario time, or frame (got t={t})")
            index, state = mapped_frame(scenario, t, count)
        else:
            index, state = (frame, "inside") if 0 <= frame < count else (None, "before" if frame < 0 else "after")
        if index is None:
            where = f"t={t:.3f} s" if frame is None else f"frame {frame}"
            span = f"{scenario.frame_time(0):.3f}-{scenario.frame_time(count):.3f} s"
            return JSONResponse(
                {"error": f"{where} is {state} the video (scenario time {span})", "state": state}, status_code=404
            )
        data = jpeg_bytes(video.frame(index))
        headers = {"Cache-Control": "no-store", "X-Video-Frame": str(index)}
        return Response(data, media_type="image/jpeg", headers=headers)

    @app.post("/api/edit")
    async def edit(request: Request) -> JSONResponse:
        body = await json_body(request)
        sc = body_scenario(body)
        try:
            new = apply_edit(sc, body.get("edit"))  # type: ignore[arg-type]
        except UserError as exc:
            raise ApiError(422, str(exc)) from None
        return JSONResponse({"scenario": new.model_dump(mode="json"), "description": new.provenance.history[-1]})

    @app.post("/api/simulate")
    async def simulate(request: Request) -> JSONResponse:
        body = await json_body(request)
        sc = body_scenario(body)
        from deepcrashtest.sim import simulate as sim

        try:
            res = await run_in_threadpool(sim, sc, controller="replay", seed=0)
        except UserError as exc:
            raise ApiError(422, str(exc)) from None
        return JSONResponse(sim_payload(res))

    @app.post("/api/project")
    async def project(request: Request) -> JSONResponse:
        body = await json_body(request)
        sc = body_scenario(body)
        count = int(time_mapping(sc, video)["frame_count"])
        sim = body.get("sim")
        if sim is None:
            poses, source = scenario_poses(sc), "scenario trajectories"
        else:
            try:
                poses = sim_poses(sim["times"], sim["vehicle_ids"], sim["states"])
            except (KeyError, TypeError, ValueError) as exc:
                raise ApiError(422, f"sim must have times, vehicle_ids and states ({exc})") from None
            source = "simulation"
        out = await run_in_threadpool(projected_frames, sc, poses, count, source)
        return JSONResponse(out)

    @app.post("/api/save")
    async def save(request: Request) -> JSONResponse:
        body = await json_body(request)
        sc = body_scenario(body)
        target = safe_target(root, body.get("filename"))
        overwrite = body.get("overwrite", False)
        if not isinstance(overwrite, bool):
            raise ApiError(400, "overwrite must be true or false")
        if target.exists() and not overwrite:
            raise ApiError(409, f"{target.name} already exists (confirm to overwrite)")
        note = f"saved by deepcrashtest view as {target.name} (opened {original.name})"
        sc = sc.evolve(provenance=sc.provenance.model_copy(update={"history": [*sc.provenance.history, note]}))
        try:
            atomic_write_text(target, sc.to_json(), force=overwrite)
        except UserError as exc:
            raise ApiError(409, str(exc)) from None
        return JSONResponse({"saved": target.name, "history": sc.provenance.history})

    return app


def bind(host: str, port: int) -> socket.socket:
    """A TCP socket bound to ``host``:``port``; a host that does not resolve or a port in use is a UserError."""
    if not 0 < port < 65536:
        raise UserError(f"--port must be 1-65535 (got {port})")
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (socket.gaierror, UnicodeError) as exc:
        raise UserError(
            f"--host {host!r}: cannot resolve the address ({getattr(exc, 'strerror', None) or exc})"
        ) from None
    family, kind, proto, _, addr = infos[0]
    sock = socket.socket(family, kind, proto)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(addr)
    except OSError as exc:
        sock.close()
        raise UserError(f"cannot listen on {host} port {port}: {exc.strerror or exc}") from None
    return sock


def serve(
    scenario_path: str | Path, host: str = "127.0.0.1", port: int = 8765, sock: socket.socket | None = None
) -> None:
    """Run the viewer until interrupted (binds ``host``: loopback by default; or serves on ``sock``)."""
    import uvicorn

    hosts = LOOPBACK_HOSTS if host in ("127.0.0.1", "localhost", "::1") else ["*"]
    app = create_app(scenario_path, allowed_hosts=hosts)
    sock = sock or bind(host, port)
    uvicorn.Server(uvicorn.Config(app, log_level="warning")).run(sockets=[sock])
