"""The CLI as a user meets it: a subprocess, exit codes, one-line errors, --json on stdout."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from deepcrashtest.cli import main
from deepcrashtest.scenario import SCHEMA_VERSION


def run(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "deepcrashtest.cli", *args], capture_output=True, text=True, cwd=cwd, timeout=300
    )


def assert_one_line_error(proc: subprocess.CompletedProcess[str], fragment: str) -> None:
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    assert fragment in lines[0], lines[0]


def test_version():
    proc = run("--version")
    assert proc.returncode == 0
    assert proc.stdout.startswith("deepcrashtest ")


@pytest.fixture(scope="module")
def bad_inputs(tmp_path_factory, kitti_root):
    from deepcrashtest.datasets.kitti.scenario import scenario_from_kitti

    d = tmp_path_factory.mktemp("bad")
    good = scenario_from_kitti(kitti_root, 3)
    data = json.loads(good.to_json())
    (d / "empty.json").write_text("")
    (d / "wrong.json").write_text("{oops")
    (d / "list.json").write_text("[]")
    v = dict(data, schema_version="9.0")
    (d / "version.json").write_text(json.dumps(v))
    nan = json.loads(good.to_json())
    nan["agents"][0]["trajectory"]["x"][1] = float("nan")
    (d / "nan.json").write_text(json.dumps(nan))  # json.dumps writes NaN
    neg = json.loads(good.to_json())
    neg["source"]["fps"] = -25.0
    (d / "negfps.json").write_text(json.dumps(neg))
    (d / "adir").mkdir()
    return d


BAD_CASES = [
    ("missing.json", "no such"),
    ("adir", "is a directory"),
    ("empty.json", "is empty"),
    ("wrong.json", "invalid JSON"),
    ("list.json", "expected a JSON object"),
    ("version.json", "schema_version 9.0 is not supported"),
    ("nan.json", "non-finite number NaN"),
    ("negfps.json", "source.fps"),
]

# every command that reads a Scenario file, with the extra arguments it needs
SCENARIO_COMMANDS = [
    ["scenario", "validate"],
    ["simulate"],
    ["search", "-o", "{out}"],
    ["export", "--format", "csv", "-o", "{out}"],
]


@pytest.mark.parametrize("command", SCENARIO_COMMANDS, ids=lambda c: c[0] if c[0] != "scenario" else "validate")
@pytest.mark.parametrize(("name", "fragment"), BAD_CASES, ids=[c[0] for c in BAD_CASES])
def test_bad_scenario_input_gives_one_line_and_exit_2(bad_inputs, tmp_path, command, name, fragment):
    args = [a.format(out=tmp_path / "out") for a in command]
    proc = run(*args, str(bad_inputs / name))
    assert_one_line_error(proc, fragment)


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["scenario", "from-kitti", "--data", "/nonexistent", "--sequence", "8", "-o", "{out}"], "not found"),
        (["scenario", "from-kitti", "--data", "{kitti}", "--sequence", "99", "-o", "{out}"], "missing for sequence"),
        (["scenario", "from-kitti", "--data", "{kitti}", "--sequence", "-1", "-o", "{out}"], "--sequence"),
        (
            ["scenario", "from-kitti", "--data", "{kitti}", "--sequence", "abc", "-o", "{out}"],
            "Invalid value for '--sequence'",
        ),
        (["extract", "{missing}", "-o", "{out}"], ""),
        (["evaluate", "kitti", "--data", "/nonexistent"], ""),
        (["evaluate", "egomotion", "--data", "/nonexistent"], ""),
        (["batch", "/nonexistent", "-o", "{out}"], ""),
        (["nosuchcommand"], "No such command"),
    ],
)
def test_bad_arguments(kitti_root, tmp_path, args, fragment):
    fmt = {"out": tmp_path / "out", "kitti": kitti_root, "missing": tmp_path / "missing.mp4"}
    proc = run(*[a.format(**fmt) for a in args])
    assert_one_line_error(proc, fragment)


def test_from_kitti_json_and_refusal_to_overwrite(kitti_root, tmp_path):
    args = ["scenario", "from-kitti", "--data", str(kitti_root), "--sequence", "3", "-o", str(tmp_path), "--json"]
    proc = run(*args)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)  # exactly one JSON object on stdout
    assert result["sequence"] == 3 and result["agents"] > 0
    before = (tmp_path / "scenario.json").read_bytes()
    proc = run(*args)
    assert_one_line_error(proc, "already exists")
    assert (tmp_path / "scenario.json").read_bytes() == before
    assert run(*args, "--force").returncode == 0


def test_schema_command_writes_valid_json(tmp_path):
    assert main(["schema", "-o", str(tmp_path / "schema.json")]) == 0
    schema = json.loads((tmp_path / "schema.json").read_text())
    assert schema["properties"]["schema_version"]["default"] == SCHEMA_VERSION
    assert main(["schema", "-o", str(tmp_path / "schema.json")]) == 2  # exists, no --force


def test_cli_imports_without_numpy():
    """`deepcrashtest --help` and the argument parsing of every command load no NumPy (~0.1 s of CPU): the
    command line reads only the detectors' names (``perception.detector_names``)."""
    code = "import sys, deepcrashtest.cli; print('numpy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize(("given", "expected"), [(None, 1), ("2", 2)])
def test_console_command_runs_blas_on_one_thread_unless_told(given, expected):
    """The console command (``cli.run``) sets OPENBLAS_NUM_THREADS to 1 before NumPy loads where the environment
    leaves it unset (no thread pool started per process), and keeps a user's own setting."""
    import os

    code = (
        "import json, deepcrashtest.cli as c\n"
        "def report(argv=None):\n"
        "    import numpy, threadpoolctl\n"
        "    pools = [p['num_threads'] for p in threadpoolctl.threadpool_info() if p['user_api'] == 'blas']\n"
        "    print(json.dumps(pools))\n"
        "    return 0\n"
        "c.main = report\n"
        "c.run()\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    if given is not None:
        env["OPENBLAS_NUM_THREADS"] = given
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
    pools = json.loads(out.stdout)
    assert pools and all(n == expected for n in pools), pools


def test_an_ego_speed_out_of_range_or_beside_a_given_camera_is_one_line(tmp_path):
    video = tmp_path / "clip.mp4"
    video.write_bytes(b"not read: the options are refused first")
    out = str(tmp_path / "out")
    assert_one_line_error(run("extract", str(video), "-o", out, "--ego-speed", "0"), "--ego-speed must be 1-400 km/h")
    refused = run("extract", str(video), "-o", out, "--ego-speed", "50", "--hfov", "90")
    assert_one_line_error(refused, "--ego-speed reads an uncalibrated camera's focal length")
