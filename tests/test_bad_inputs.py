"""The bad-input corpus of issue 18: every case gives one clear line and exit 2 (or a result), never an internal
error, and a failed run leaves no output folder behind. Small generated files only; run in-process for speed."""

from __future__ import annotations

import json
import os
import socket
import stat
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from deepcrashtest.cli import main
from deepcrashtest.errors import UserError
from deepcrashtest.fileio import output_set
from deepcrashtest.scenario import Scenario, Trajectory
from deepcrashtest.trajectory.pipeline import process_scenario
from trajectory_cases import CLASS_CASES, EGO_SPEED, FPS, raw_scenario, track, vehicle


def cli(capsys: pytest.CaptureFixture[str], *args: Any) -> tuple[int, str, str]:
    rc = main([str(a) for a in args])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def assert_clear_error(rc: int, err: str, fragment: str = "") -> None:
    """Exit 2, exactly one line on stderr, no traceback, no internal error, the fragment in the line."""
    lines = err.strip().splitlines()
    assert rc == 2, (rc, err)
    assert len(lines) == 1, err
    assert "internal error" not in err and "Traceback" not in err, err
    assert fragment in lines[0], lines[0]


@pytest.fixture(scope="module")
def good() -> Scenario:
    """A small processed scenario: the ego at 10 m/s and one car ahead in the next lane (10 s, 10 fps)."""
    return process_scenario(raw_scenario([CLASS_CASES["D0T1"]]))


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory, good: Scenario) -> Path:
    """The generated corpus: one small file per bad scenario input."""
    d = tmp_path_factory.mktemp("corpus")
    base = json.loads(good.to_json())

    def variant(name: str, edit: Any) -> None:
        data = json.loads(json.dumps(base))
        edit(data)
        (d / name).write_text(json.dumps(data))

    variant("coord_1e308.json", lambda s: s["agents"][0]["trajectory"]["x"].__setitem__(1, 1e308))
    variant("length_1e308.json", lambda s: s["agents"][0].__setitem__("length", 1e308))
    variant("length_zero.json", lambda s: s["ego"].__setitem__("width", 0.01))
    variant("string_number.json", lambda s: s["ego"].__setitem__("length", "12.5"))
    variant("string_coord.json", lambda s: s["ego"]["trajectory"]["x"].__setitem__(0, "0.0"))
    variant("bool_id.json", lambda s: s["agents"][0].__setitem__("id", True))
    variant("float_frame.json", lambda s: s["agents"][0].__setitem__("first_frame", 2.0))
    variant("nul_name.json", lambda s: s.__setitem__("name", "crash\x00one"))
    variant("ctrl_name.json", lambda s: s.__setitem__("name", "crash\x1b[31mred"))
    variant("newline_name.json", lambda s: s.__setitem__("name", "two\nlines"))
    variant("surrogate_name.json", lambda s: s.__setitem__("name", "\ud800"))
    variant("long_name.json", lambda s: s.__setitem__("name", "x" * 1000))
    variant("negative_seed.json", lambda s: s["provenance"].__setitem__("seed", -1))
    variant("time_1e300.json", lambda s: s["ego"]["trajectory"]["t"].__setitem__(-1, 1e300))
    variant("yaw_1e300.json", lambda s: s["ego"]["trajectory"]["yaw"].__setitem__(0, 1e300))
    variant("road_1e308.json", lambda s: s["road"]["centerline_x"].__setitem__(0, -1e308))
    variant("speed_200.json", lambda s: s["ego"]["trajectory"]["speed"].__setitem__(3, 200.0))
    variant("fx_huge.json", lambda s: s["camera"].__setitem__("fx", 1e300))
    (d / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    (d / "deep_object.json").write_text('{"a":' * 50_000 + "1" + "}" * 50_000)
    (d / "binary.json").write_bytes(np.random.default_rng(0).integers(0, 256, 256, dtype=np.uint8).tobytes())
    (d / "latin1.json").write_bytes(b'{"name": "caf\xe9"}')
    return d


SCENARIO_CASES = [
    ("coord_1e308.json", "less than or equal to 100000"),
    ("length_1e308.json", "agents.0.length"),
    ("length_zero.json", "ego.width"),
    ("string_number.json", "expected a number, got str '12.5'"),
    ("string_coord.json", "ego.trajectory.x.0: Input should be a valid number"),
    ("bool_id.json", "expected an integer"),
    ("float_frame.json", "expected an integer"),
    ("nul_name.json", "U+0000"),
    ("ctrl_name.json", "U+001B"),
    ("newline_name.json", "one line"),
    ("surrogate_name.json", "U+D800"),
    ("long_name.json", "name"),
    ("negative_seed.json", "provenance.seed"),
    ("time_1e300.json", "ego.trajectory.t"),
    ("yaw_1e300.json", "ego.trajectory.yaw"),
    ("road_1e308.json", "road.centerline_x"),
    ("speed_200.json", "physical limit"),
    ("fx_huge.json", "camera.fx"),
    ("deep.json", "nested too deeply"),
    ("deep_object.json", "nested too deeply"),
    ("binary.json", "not a text file"),
    ("latin1.json", "not a text file"),
]


@pytest.mark.parametrize(("name", "fragment"), SCENARIO_CASES, ids=[c[0] for c in SCENARIO_CASES])
def test_bad_scenarios_are_refused_by_every_reader(capsys, corpus, tmp_path, name, fragment):
    """Issue 18 items 5, 6, 7: what ``validate`` accepts, simulate/search/export can use; the rest is refused."""
    for command in (["scenario", "validate"], ["simulate"], ["search", "-o", tmp_path / "s"], ["export"]):
        extra = ["--format", "csv", "-o", tmp_path / "e"] if command == ["export"] else []
        rc, _, err = cli(capsys, *command, *extra, corpus / name)
        assert_clear_error(rc, err, fragment)
    assert not (tmp_path / "s").exists() and not (tmp_path / "e").exists()


def test_values_at_the_bounds_simulate_and_export(capsys, good, tmp_path):
    """Coordinates near the +-1e5 m bound and the largest sizes are valid: they simulate and export."""
    data = json.loads(good.to_json())
    for v in [data["ego"], *data["agents"]]:
        v["trajectory"]["x"] = [x + 99_000.0 for x in v["trajectory"]["x"]]
        v["spline"] = None
    data["road"]["centerline_x"] = [x + 99_000.0 for x in data["road"]["centerline_x"]]
    data["agents"][0]["length"] = 30.0
    data["agents"][0]["width"] = 0.1
    path = tmp_path / "far.json"
    path.write_text(json.dumps(data))
    assert cli(capsys, "simulate", path, "--json")[0] == 0
    assert cli(capsys, "export", path, "--format", "openscenario", "-o", tmp_path / "x")[0] == 0


def _standing_ego(good: Scenario, start_delay_s: float) -> dict[str, Any]:
    """``good`` as a file whose ego is one sample at t = 0 (no agents, no crash): nobody moves."""
    data = json.loads(good.to_json())
    traj = data["ego"]["trajectory"]
    for key in list(traj):
        if isinstance(traj[key], list):
            traj[key] = traj[key][:1]
    data["ego"].update(spline=None, start_delay_s=start_delay_s, last_frame=data["ego"]["first_frame"])
    data["agents"], data["collision"] = [], None
    return data


def test_nobody_moving_exports_and_an_ego_after_its_samples_is_one_line(capsys, good, tmp_path):
    """Found by bench/fuzz_cli.py on schema-valid scenarios: a scenario where nobody moves ended in "ValueError:
    no maneuver group added to the act" (OpenSCENARIO; now an Init-only file) and an ego whose start delay lies
    after its only sample in "IndexError" (CommonRoad; now one line naming the ego's span)."""
    still = tmp_path / "still.json"
    still.write_text(json.dumps(_standing_ego(good, 0.0)))
    rc, _, err = cli(capsys, "export", still, "--format", "openscenario", "-o", tmp_path / "x")
    assert rc == 0, err
    import scenariogeneration
    import xmlschema

    schemas = Path(scenariogeneration.__file__).resolve().parents[1] / "schemas"
    xmlschema.XMLSchema(str(schemas / "OpenSCENARIO_1_2.xsd")).validate(str(tmp_path / "x" / "scenario.xosc"))
    late = tmp_path / "late.json"
    late.write_text(json.dumps(_standing_ego(good, 0.5)))
    rc, _, err = cli(capsys, "export", late, "--format", "commonroad", "-o", tmp_path / "y")
    assert_clear_error(rc, err, "ego trajectory spans no CommonRoad time step")
    assert not (tmp_path / "y").exists()


def test_search_around_an_ego_whose_samples_jump_across_the_world_is_one_line(capsys, good, tmp_path):
    """Found by bench/fuzz_cli.py: samples alternating between x = +-99 km (inside the schema's +-100 km) made the
    least-squares ego spline overshoot past 100 km: "ValidationError ... for SplineParams" at exit 1."""
    data = json.loads(good.to_json())
    t = [0.0, 0.01, 0.02, 0.03, 5.0]
    data["ego"]["trajectory"] = {
        "t": t,
        "x": [99_000.0, -99_000.0, 99_000.0, -99_000.0, 99_000.0],
        "y": [0.0] * 5,
        "yaw": [0.0] * 5,
        "speed": [10.0] * 5,
    }
    data["ego"].update(spline=None, last_frame=50)
    path = tmp_path / "jumps.json"
    path.write_text(json.dumps(data))
    assert cli(capsys, "scenario", "validate", path)[0] == 0
    rc, _, err = cli(capsys, "search", path, "-o", tmp_path / "s", "--starts", "2", "--noise-variants", "1",
                     "--no-video", "--workers", "1")  # fmt: skip
    assert_clear_error(rc, err, "fitted spline leaves the world")
    assert not (tmp_path / "s").exists()


def test_commonroad_export_of_a_200_km_road_stays_small(capsys, good, tmp_path):
    """Found by bench/fuzz_cli.py: a schema-valid road of ~200 km (waypoints at x = +-99 km) was sampled every
    metre into each lanelet (2 minutes of CPU); now at most MAX_LANELET_VERTICES samples per boundary."""
    from deepcrashtest.export.commonroad import MAX_LANELET_VERTICES

    data = json.loads(good.to_json())
    data["road"].update(centerline_x=[-99_000.0, 99_000.0], centerline_y=[0.0, 0.0])
    path = tmp_path / "long_road.json"
    path.write_text(json.dumps(data))
    rc, _, err = cli(capsys, "export", path, "--format", "commonroad", "-o", tmp_path / "cr")
    assert rc == 0, err
    xml = (tmp_path / "cr" / "commonroad.xml").read_text()
    lanelets = xml.count("<lanelet ")
    assert lanelets == good.road.lane_count + good.road.oncoming_lane_count
    assert xml.count("<point>") <= lanelets * 3 * (MAX_LANELET_VERTICES + 2) + 200  # + the obstacles' shapes


@pytest.mark.parametrize(
    ("option", "fragment"),
    [
        (["--fps", "1e-12"], "--fps must be a positive number of frames per second, 0.01-10000"),
        (["--fps", "1e308"], "--fps must be a positive number of frames per second, 0.01-10000"),
        (["--fps", "10", "--camera-height", "inf"], "camera height must be > 0 and <= 100 m"),
        (["--fps", "10", "--camera-height", "1e308"], "camera height must be > 0 and <= 100 m"),
        (["--fps", "10", "--driving-side", "middle"], "--driving-side must be one of right, left (got 'middle')"),
    ],
)
def test_extract_refuses_absurd_frame_rates_and_camera_heights(capsys, tmp_path, option, fragment):
    """Found by bench/fuzz_cli.py: --fps 1e-12 / 1e308 ended in the video writer's ValueError / OverflowError and
    --camera-height inf in "Out of range float values are not JSON compliant"; now one line, no output folder."""
    import cv2

    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(3):
        cv2.imwrite(str(frames / f"{k:06d}.png"), np.full((48, 64, 3), 40 * k, np.uint8))
    rc, _, err = cli(capsys, "extract", frames, "-o", tmp_path / "x", "--no-lanes", "--no-report", *option, "--json")
    assert_clear_error(rc, err, fragment)
    assert not (tmp_path / "x").exists()


def test_an_output_onto_its_own_input_is_refused_even_with_force(capsys, good, tmp_path):
    """Found by bench/fuzz_cli.py: ``simulate sc.json --video sc.json --force`` and ``report sc.json -o sc.json
    --force`` replaced the scenario with a video / an HTML page; now one line, the input left as it was."""
    sc = good.save(tmp_path / "sc.json")
    before = sc.read_bytes()
    for args in (["simulate", sc, "--duration", "1", "--video", sc], ["report", sc, "-o", sc]):
        rc, _, err = cli(capsys, *args, "--force")
        assert_clear_error(rc, err, "is also an input of this command")
        assert sc.read_bytes() == before


@pytest.mark.parametrize("special", ["fifo", "/dev/zero", "/dev/urandom"])
def test_special_files_are_not_regular_files(capsys, tmp_path, special):
    """Item 13: a FIFO or a device is "not a regular file", not "is empty" (and nothing hangs)."""
    path = tmp_path / "pipe.json"
    if special == "fifo":
        os.mkfifo(path)
    else:
        path = Path(special)
    rc, _, err = cli(capsys, "scenario", "validate", path)
    assert_clear_error(rc, err, "not a regular file")


@pytest.mark.parametrize(
    "command",
    [
        ["schema", "-o", "{fifo}"],
        ["scenario", "build", "{raw}", "-o", "{fifo}"],
        ["report", "{sc}", "-o", "{fifo}"],
        ["simulate", "{sc}", "--duration", "1", "--video", "{fifo}"],
    ],
    ids=lambda c: "-".join(c[:2]) if c[0] == "scenario" else c[0],
)
def test_force_never_replaces_a_device_or_fifo(capsys, good, tmp_path, command):
    """Found by bench/fuzz_cli.py: ``-o /dev/null --force`` renamed the output onto /dev/null, replacing the
    device with a regular file (as root). A FIFO stands in for the device here: refused, left as it was."""
    sc = good.save(tmp_path / "sc.json")
    raw = raw_scenario([CLASS_CASES["D0T1"]]).save(tmp_path / "raw.json")
    fifo = tmp_path / "out.pipe"
    os.mkfifo(fifo)
    args = [a.format(sc=sc, raw=raw, fifo=fifo) for a in command]
    rc, _, err = cli(capsys, *args, "--force")
    assert_clear_error(rc, err, "not a regular file")
    assert stat.S_ISFIFO(fifo.stat().st_mode)


@pytest.mark.parametrize(
    "command",
    [
        ["simulate", "{sc}"],
        ["search", "{sc}", "-o", "{out}"],
        ["scenario", "build", "{sc}", "-o", "{out}/p.json"],
        ["extract", "{sc}", "-o", "{out}"],
        ["batch", "{dir}", "-o", "{out}"],
        ["scenario", "from-kitti", "--data", "{dir}", "--sequence", "3", "-o", "{out}"],
    ],
    ids=lambda c: "-".join(c[:2]) if c[0] == "scenario" else c[0],
)
@pytest.mark.parametrize("seed", ["-1", "1.5", "abc"])
def test_one_seed_rule_at_parse_time(capsys, good, tmp_path, command, seed):
    """Item 8: --seed is a non-negative integer for every command, checked before any work or output."""
    sc = good.save(tmp_path / "in" / "sc.json")
    args = [a.format(sc=sc, out=tmp_path / "out", dir=tmp_path / "in") for a in command]
    rc, _, err = cli(capsys, *args, "--seed", seed)
    assert_clear_error(rc, err, "--seed")
    assert not (tmp_path / "out").exists()


def test_seed_rule_in_the_library(good):
    from deepcrashtest.sim import simulate, simulate_batch

    for call in (
        lambda: simulate(good, seed=-1),
        lambda: simulate_batch(good, np.zeros((2, 2)), seed=-1),
        lambda: process_scenario(raw_scenario([]), seed=-1),
    ):
        with pytest.raises(UserError, match="--seed must be a non-negative integer"):
            call()


@pytest.mark.parametrize(
    ("option", "fragment"),
    [
        (["--workers", "0"], "--workers"),
        (["--engine", "spark"], "--engine"),
        (["--controller", "nosuch"], "controller 'nosuch'"),
        (["--controller", "nosuchmodule:f"], "cannot import"),
        (["--method", "best"], "--method"),
        (["--starts", "0"], "--starts"),
    ],
)
def test_batch_checks_every_option_before_the_first_input(capsys, good, tmp_path, option, fragment):
    """Item 9: a bad batch option is refused at once: no manifest, no output folder, no input processed."""
    good.save(tmp_path / "in" / "a.json")
    rc, _, err = cli(capsys, "batch", tmp_path / "in", "-o", tmp_path / "out", *option)
    assert_clear_error(rc, err, fragment)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("option", "fragment"),
    [
        (["--starts", "1000000000000"], "--starts x --noise-variants"),
        (["--noise-variants", "1000000000000"], "--starts x --noise-variants"),
        (["--box-lateral", "1e308"], "--box-lateral must be 0-1000 m"),
        (["--box-longitudinal", "1e308"], "--box-longitudinal must be 0-1000 m"),
        (["--box-lateral", "-0.5"], "--box-lateral"),
        (["--box-longitudinal", "-1"], "--box-longitudinal"),
        (["--noise-sigma", "1e308"], "--noise-sigma must be 0-100 m"),
        (["--noise-sigma", "-1"], "--noise-sigma"),
        (["--workers", "1000000000000"], "--workers must be 1-1024"),
    ],
)
def test_search_refuses_huge_and_non_finite_option_values(capsys, good, tmp_path, option, fragment):
    """Found by bench/fuzz_cli.py: the huge values ended in a MemoryError, an OverflowError, 'Maximum allowed size
    exceeded' or RuntimeWarnings before one line; now one line before any work, and no output folder."""
    sc = good.save(tmp_path / "sc.json")
    args = ["search", sc, "-o", tmp_path / "out", "--starts", "2", "--noise-variants", "1", "--no-video"]
    rc, _, err = cli(capsys, *args, *option)
    assert_clear_error(rc, err, fragment)
    assert not (tmp_path / "out").exists()
    if option[0] == "--workers":  # batch: the same rule, before the first input
        rc, _, err = cli(capsys, "batch", tmp_path, "-o", tmp_path / "out", *option)
        assert_clear_error(rc, err, fragment)


def test_view_refuses_a_bad_host_or_a_port_in_use(capsys, good, tmp_path):
    """Item 10: no "viewer on" banner and no uvicorn traceback; one line, exit 2."""
    sc = good.save(tmp_path / "sc.json")
    rc, _, err = cli(capsys, "view", sc, "--host", "no-such-host.invalid")
    assert_clear_error(rc, err, "cannot resolve")
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        rc, _, err = cli(capsys, "view", sc, "--port", busy.getsockname()[1])
    assert_clear_error(rc, err, "cannot listen")
    assert "viewer on" not in err


CONTROLLERS = {
    "raises": ("def ctl(obs):\n    raise RuntimeError('boom')\n", "ctl", "controller ctl raised RuntimeError: boom"),
    "string": ("def ctl(obs):\n    return 'brake'\n", "ctl", "returned str 'brake'"),
    "nan": ("import math\ndef ctl(obs):\n    return math.nan, 0.0\n", "ctl", "non-finite acceleration"),
    "shape": ("def ctl(obs):\n    return [1.0, 2.0, 3.0], 0.0\n", "ctl", "acceleration list"),
    "not_callable": ("ctl = 42\n", "ctl", "'ctl' in"),
    "missing": ("x = 1\n", "ctl", "has no 'ctl'"),
    "syntax": ("def ctl(obs)\n", "ctl", "loading"),
    "bad_class": (
        "class Ctl:\n    def __init__(self):\n        raise ValueError('no config')\n",
        "Ctl",
        "creating Ctl() failed",
    ),
    "class_not_callable": ("class Ctl:\n    pass\n", "Ctl", "not callable"),
}


@pytest.mark.parametrize("case", list(CONTROLLERS))
def test_user_controllers_are_named_with_their_problem(capsys, good, tmp_path, case):
    """Item 11: a faulty user controller is the user's input: named, one line, exit 2 (simulate and search)."""
    code, attr, fragment = CONTROLLERS[case]
    mod = tmp_path / f"user_{case}.py"
    mod.write_text(code)
    sc = good.save(tmp_path / "sc.json")
    spec = f"{mod}:{attr}"
    rc, _, err = cli(capsys, "simulate", sc, "--controller", spec)
    assert_clear_error(rc, err, fragment)
    rc, _, err = cli(capsys, "search", sc, "-o", tmp_path / "s", "--controller", spec, "--method", "random",
                     "--starts", "2", "--noise-variants", "1", "--no-video", "--workers", "1")  # fmt: skip
    assert_clear_error(rc, err, fragment)
    assert not (tmp_path / "s").exists()


def test_early_errors_leave_no_folder(capsys, good, tmp_path):
    """Item 12: a run that fails before (or while) writing leaves no empty output folder, parents included."""
    sc = good.save(tmp_path / "sc.json")
    out = tmp_path / "a" / "b" / "out"
    cases = [
        ["search", sc, "-o", out, "--method", "best"],
        ["search", sc, "-o", out, "--duration", "-1"],
        ["export", sc, "--format", "xml", "-o", out],
        ["extract", sc, "-o", out, "--detector", "nosuch"],
        ["extract", tmp_path / "missing.mp4", "-o", out],
        ["scenario", "build", sc, "-o", out / "p.json"],  # a processed scenario is not a raw one
        ["simulate", sc, "--video", out / "v.mp4", "--controller", "nosuch"],
    ]
    for args in cases:
        rc, _, err = cli(capsys, *args)
        assert_clear_error(rc, err)
        assert not (tmp_path / "a").exists(), args


def test_killed_runs_leave_nothing_that_survives_the_next_run(capsys, good, tmp_path):
    """Item 12: a killed run's staging folder and temporary files (a dead process id) are removed by the next."""
    sc = good.save(tmp_path / "sc.json")
    out = tmp_path / "exp"
    dead = _dead_pid()
    (tmp_path / f".exp.{dead}.abc.partial").mkdir()
    (tmp_path / f".exp.{dead}.abc.partial" / "trajectories.csv").write_text("half")
    out.mkdir()
    (out / ".trajectories.csv.k3j_x9.csv").write_text("")  # an old-style temporary file, no process id
    (out / "notes.txt").write_text("the user's own file")
    rc, _, err = cli(capsys, "export", sc, "--format", "csv", "-o", out)
    assert rc == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exp", "sc.json"]
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt", "trajectories.csv"]


def _dead_pid() -> int:
    pid = 4_000_000
    while True:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return pid
        except PermissionError:
            pass
        pid += 1


def test_output_set_is_all_from_one_run(tmp_path):
    """Items 2/3/12: --force replaces the whole set; a failed run changes nothing and leaves no staging folder."""
    out = tmp_path / "set"
    with output_set(out, ["a.txt", "b.txt"]) as stage:
        (stage / "a.txt").write_text("run 1")
        (stage / "b.txt").write_text("run 1")
    with pytest.raises(UserError, match="already exists"):
        with output_set(out, ["a.txt", "b.txt"]):
            pass
    with pytest.raises(RuntimeError):
        with output_set(out, ["a.txt", "b.txt"], force=True) as stage:
            (stage / "a.txt").write_text("run 2")
            raise RuntimeError("the run fails")
    assert {p.name: p.read_text() for p in out.iterdir()} == {"a.txt": "run 1", "b.txt": "run 1"}
    with output_set(out, ["a.txt", "b.txt"], force=True) as stage:
        (stage / "a.txt").write_text("run 3")  # this run makes a.txt only: run 1's b.txt must go
    assert {p.name: p.read_text() for p in out.iterdir()} == {"a.txt": "run 3"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["set"]


@pytest.mark.skipif(os.geteuid() == 0, reason="root ignores folder permissions")
def test_read_only_folder_names_the_output_not_a_temporary_file(capsys, good, tmp_path):
    """Item 13: the error names the output the user asked for."""
    sc = good.save(tmp_path / "sc.json")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(stat.S_IRUSR | stat.S_IXUSR)
    try:
        rc, _, err = cli(capsys, "export", sc, "--format", "csv", "-o", ro / "out")
        assert_clear_error(rc, err, str(ro / "out"))
        rc, _, err = cli(capsys, "scenario", "build", sc, "-o", ro / "p.json")
        assert_clear_error(rc, err)
        assert ".p.json" not in err
    finally:
        ro.chmod(stat.S_IRWXU)


def test_teleporting_agent_is_dropped_with_a_warning():
    """Items 1 and 5: an agent track that jumps 200 m in 0.1 s never makes stage 2 fail with an internal error."""
    steady = track(lambda t: (20 + EGO_SPEED * t, -3.5 + 0 * t), 0, 100)
    a = steady.arrays()
    x = a["x"] + 200.0 * (a["t"] > 5)  # the positions jump; the stated speeds stay plausible
    jump = vehicle(1, Trajectory.from_arrays(a["t"], x, a["y"], a["yaw"], a["speed"], observed=np.ones(len(x), bool)))
    sc = process_scenario(raw_scenario([jump, CLASS_CASES["D1T1"]]))
    assert 1 not in [a.id for a in sc.agents] or max(max(a.trajectory.speed) for a in sc.agents) <= 90.0
    assert any("agent 1" in w for w in sc.warnings) or 1 in [a.id for a in sc.agents]


def test_search_without_a_crash_says_so(capsys, good, tmp_path):
    """Item 13: the original does not collide: the summary says there is no crash to avoid (no "safe" claims)."""
    sc = good.save(tmp_path / "sc.json")
    args = ["search", sc, "-o", tmp_path / "s", "--method", "random", "--starts", "3", "--noise-variants", "1"]
    rc, out, err = cli(capsys, *args, "--no-video", "--workers", "1")
    assert rc == 0, err
    assert "no crash to avoid" in out and "safe" not in out.replace("counts as safe", "")
    summary = json.loads((tmp_path / "s" / "summary.json").read_text())
    assert summary["original"]["collided"] is False and "no crash to avoid" in summary["note"]


def test_infeasible_variants_are_recorded_not_errors(good):
    """Item 4: a variant whose path breaks the physical limits is a recorded, skipped result."""
    import pandas as pd

    from deepcrashtest.search.outputs import write_variants
    from deepcrashtest.search.space import SearchSpace

    space = SearchSpace.for_scenario(good)
    theta = np.zeros((2, space.dim))
    theta[1, 2:] = 40.0 * (-1.0) ** np.arange(space.dim - 2)  # control points zig-zag by 40 m: no car can drive it
    df = pd.DataFrame({"variant": [0, 1], "method": ["random"] * 2, "safe": [False, True], "change_m": [0.0, 1.0]})
    paths, problems, best = write_variants(good, space, df, theta, Path("/nonexistent"), {"seed": 0}, 4, False)
    assert paths == [] and best is None and list(problems) == [1] and "physical limit" in problems[1]


def test_no_vehicles_is_said(capsys, tmp_path):
    """Item 13: a video without road users says "no vehicles found" (a grey 10-frame clip)."""
    import cv2

    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(10):
        cv2.imwrite(str(frames / f"{i:04d}.png"), np.full((96, 128, 3), 120, np.uint8))
    rc, out, err = cli(capsys, "extract", frames, "-o", tmp_path / "x", "--fps", FPS, "--no-geometry", "--json")
    assert rc == 0, err
    assert "no vehicles found in the video" in json.loads(out)["warnings"]


@pytest.mark.parametrize("width, height", [(4, 400), (4000, 8)])
def test_a_sliver_of_a_video_extracts_with_its_report(capsys, tmp_path, width, height):
    """Valid if odd videos. 4 x 400 px: the report's contact sheet made 320 x 32,000-px thumbnails, a 64,000-row
    sheet no JPEG holds ("could not encode the contact sheet", exit 2); thumbnails are now at most twice as tall as
    wide; and the default camera of so narrow a picture was a 0.6 deg view, refused as a bad --hfov. 4000 x 8 px,
    processed at 1280 x 2 (--max-width): the detector's and the bonnet finder's downscales came to 0 rows (an
    internal error)."""
    import cv2

    frames = tmp_path / "frames"
    frames.mkdir()
    rng = np.random.default_rng(0)
    for i in range(12):
        cv2.imwrite(str(frames / f"{i:04d}.png"), rng.integers(0, 255, (height, width, 3), dtype=np.uint8))
    rc, out, err = cli(capsys, "extract", frames, "-o", tmp_path / "x", "--fps", FPS, "--json")
    assert rc == 0, err
    assert (tmp_path / "x" / "report.html").is_file()


def test_along_road_without_samples_is_no_lane_evidence():
    """A real clip (DAD 000487, 20 frames) ended in an internal error: a road user whose observed samples were
    all cut away made the lane inference project zero points."""
    from deepcrashtest.trajectory.road import along_road
    from deepcrashtest.trajectory.roadframe import RoadFrame

    frame = RoadFrame.from_path(np.column_stack([np.linspace(0, 50, 20), np.zeros(20)]), 2.0, heading=0.0)
    assert along_road(frame, np.zeros((0, 2)), 0.0) is False
    assert along_road(frame, np.array([[10.0, 1.0], [20.0, 1.0]]), 0.0) is True


@pytest.fixture(scope="module")
def ccd53_small() -> list[np.ndarray]:
    """The first 25 frames of a real crash clip (CCD 000053, 10 fps) at a quarter of its size (320x180 px)."""
    from itertools import islice

    import av

    from conftest import DATA, need

    with av.open(str(need(DATA / "crash_ccd" / "ccd_000053.mp4"))) as c:
        return [f.to_ndarray(format="bgr24")[::4, ::4] for f in islice(c.decode(video=0), 25)]


def write_clip(path: Path, frames: list[np.ndarray], times_s: list[float] | None = None) -> Path:
    """An H.264 clip of ``frames`` (BGR) at 10 fps, or at the frame times ``times_s`` (s, whole milliseconds)."""
    from fractions import Fraction

    import av

    with av.open(str(path), "w") as c:
        s = c.add_stream("libx264", rate=10)
        s.height, s.width = frames[0].shape[:2]
        if times_s is not None:
            s.codec_context.time_base = Fraction(1, 1000)
        for i, img in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="bgr24")
            if times_s is not None:
                frame.pts, frame.time_base = round(times_s[i] * 1000), Fraction(1, 1000)
            c.mux(s.encode(frame))
        c.mux(s.encode())
    return path


def test_one_frame_video_and_crash_at_frame_0_say_what_to_give(capsys, tmp_path, ccd53_small):
    """A 1-frame clip cut from a real crash clip: extract exits 2 with one line that says why and what
    works (--no-geometry, which then writes its tracks); --crash 0 on a 2-frame clip names frame 0 as the
    first frame (not "outside the video") and the range to give."""
    clips = {n: write_clip(tmp_path / f"{n}.mp4", ccd53_small[:n]) for n in (1, 2)}
    rc, _, err = cli(capsys, "extract", clips[1], "-o", tmp_path / "a", "--no-lanes", "--no-report")
    assert_clear_error(rc, err, "fewer than 2 frames")
    assert "--no-geometry" in err and not (tmp_path / "a").exists()
    rc, _, err = cli(capsys, "extract", clips[1], "-o", tmp_path / "b", "--no-geometry")
    assert rc == 0 and (tmp_path / "b" / "tracks.csv").is_file(), err
    rc, _, err = cli(capsys, "extract", clips[2], "-o", tmp_path / "c", "--crash", "0", "--no-lanes", "--no-report")
    assert_clear_error(rc, err, "frame 0 is the first frame")
    assert "give 1..1" in err


def test_batch_names_the_video_that_failed(capsys, tmp_path, ccd53_small):
    """A batch over a folder with a 1-frame clip: the input fails (exit 1, the batch goes on) and its manifest
    error names the file (it said only "the video has fewer than 2 frames")."""
    (tmp_path / "in").mkdir()
    clip = write_clip(tmp_path / "in" / "one_frame.mp4", ccd53_small[:1])
    rc, _, err = cli(capsys, "batch", tmp_path / "in", "-o", tmp_path / "out", "--workers", 1)
    assert rc == 1, err
    entry = json.loads((tmp_path / "out" / "manifest.json").read_text())["items"]["one_frame"]
    assert entry["status"] == "failed" and str(clip) in entry["error"] and "fewer than 2 frames" in entry["error"]


def test_dashboard_rows_beyond_the_frame_refused_within_it_cut_with_a_warning(capsys, tmp_path, ccd53_small):
    """``--dashboard-rows`` on a real 320x180 clip: 180 or more would hide the whole frame (a value for
    another resolution): one line, exit 2, no folder (it was cut to 60 silently); 100 is cut to a third of
    the frame (60), and the run says so in one warning (it said nothing)."""
    clip = write_clip(tmp_path / "c.mp4", ccd53_small)
    rc, _, err = cli(capsys, "extract", clip, "-o", tmp_path / "a", "--dashboard-rows", 180)
    assert_clear_error(rc, err, "--dashboard-rows 180 hides the whole 320x180 frame")
    assert not (tmp_path / "a").exists()
    rc, out, err = cli(
        capsys, "extract", clip, "-o", tmp_path / "b", "--dashboard-rows", 100, "--no-lanes", "--no-report"
    )
    assert rc == 0, err
    notes = [line for line in out.splitlines() if "--dashboard-rows" in line]
    assert notes == ["warning: --dashboard-rows 100 cut to 60 (a third of the 180-row frame: the geometry needs the "
                     "road below the horizon)"]  # fmt: skip
    raw = Scenario.load(tmp_path / "b" / "scenario_raw.json")
    assert raw.provenance.parameters["dashboard_rows"] == 60


def test_variable_frame_rate_is_said_with_its_range(capsys, tmp_path, ccd53_small):
    """A real clip re-timed to 30 fps for 10 frames, then 10 fps: the summary line says the rate is variable
    with its range (it showed only the container's mean, 15.8 fps); the same frames at a constant 30 fps
    (timestamps rounded to milliseconds: 33 or 34 ms apart) keep the plain rate."""
    vfr = [i / 30 for i in range(10)] + [9 / 30 + i / 10 for i in range(1, 11)]
    clips = {"vfr": vfr, "cfr": [i / 30 for i in range(20)]}
    lines = {}
    for name, times in clips.items():
        clip = write_clip(tmp_path / f"{name}.mp4", ccd53_small[:20], times)
        rc, out, err = cli(capsys, "extract", clip, "-o", tmp_path / name, "--no-geometry")
        assert rc == 0, err
        lines[name] = out.splitlines()[0]
    assert "(320x180 @ variable 10.0-30.3 fps, mean 15.785)" in lines["vfr"], lines["vfr"]  # FFmpeg's mean
    assert "(320x180 @ 27.248 fps)" in lines["cfr"], lines["cfr"]  # FFmpeg's mean of a short clip


@pytest.mark.parametrize(
    ("yaml_text", "fragment"),
    [
        ("fx: -5\ncx: 80\ncy: 45\n", "(fx: Input should be greater than 0;"),
        ("hfov_deg: 60\nheight_m: -1\n", "height_m"),
        ("fx: 800\ncx: 5000\ncy: 300\n", "lies outside the"),
    ],
)
def test_camera_file_out_of_range_is_one_line(capsys, tmp_path, yaml_text, fragment):
    """A camera YAML that parses but breaks the Camera's bounds (negative focal length or height) is refused
    in one line naming the field (pydantic's own text spans four lines), before the real clip is read; so is
    a principal point outside the video's frame (it was accepted, and the ego's speed came out 0)."""
    from conftest import DATA, need

    cam = tmp_path / "cam.yaml"
    cam.write_text(yaml_text)
    clip = need(DATA / "crash_ccd" / "ccd_000053.mp4")
    rc, _, err = cli(capsys, "extract", clip, "-o", tmp_path / "x", "--camera", cam, "--max-frames", 2)
    assert_clear_error(rc, err, fragment)
    assert not (tmp_path / "x").exists()
