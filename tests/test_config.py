"""The one configuration file: merged over the stages' defaults, strict on keys and types, used by the CLI."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from deepcrashtest.config import Config, load_config, merge_config
from deepcrashtest.errors import UserError
from deepcrashtest.search.run import SearchConfig
from deepcrashtest.trajectory.params import Stage2Params


def test_defaults_are_the_stages_own():
    cfg = load_config(None)
    assert cfg.stage2 == Stage2Params() and cfg.search == SearchConfig()
    assert set(cfg.as_dict()) == {"stage2", "search"}


def test_file_overrides_and_cli_overrides_file(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("stage2:\n  stepback_accel_mps2: 2.5\nsearch:\n  starts: 64\n  box_lateral: 3\n")
    cfg = load_config(path)
    assert cfg.stage2.stepback_accel_mps2 == 2.5 and cfg.stage2.road_sigma_m == Stage2Params().road_sigma_m
    assert cfg.search.starts == 64 and cfg.search.box_lateral == 3
    given = cfg.with_search(starts=8, noise_variants=None)
    assert given.starts == 8 and given.noise_variants == SearchConfig().noise_variants and given.box_lateral == 3


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("stage3: {}\n", r"unknown section\(s\) \['stage3'\]"),
        ("search:\n  startz: 3\n", r"unknown field\(s\) \['startz'\]"),
        ("search:\n  starts: '12'\n", "search.starts: expected int"),
        ("search:\n  starts: 1.5\n", "search.starts: expected int"),
        ("stage2:\n  road_sigma_m: .nan\n", "stage2.road_sigma_m: expected float"),
        ("stage2:\n  road_sigma_m: -1\n", "must be > 0"),
        ("stage2:\n  driving_side: middle\n", "driving_side must be one of right, left"),
        ("stage2:\n  driving_side: 1\n", "stage2.driving_side: expected str"),
        ("[1, 2]\n", "expected a mapping of sections"),
        ("search: [1]\n", "must be a mapping"),
        ("search: {starts: [\n", "invalid YAML at line"),
    ],
)
def test_bad_files_name_the_problem(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(UserError, match=message):
        load_config(path)


def test_merge_keeps_base():
    base = merge_config(Config(), {"search": {"starts": 5}})
    again = merge_config(base, {"stage2": {"road_sigma_m": 0.5}})
    assert again.search.starts == 5 and again.stage2.road_sigma_m == 0.5


def test_cli_bad_config_is_one_line_exit_2(tmp_path, kitti8_raw):
    raw = kitti8_raw.save(tmp_path / "raw.json")
    cfg = tmp_path / "c.yaml"
    cfg.write_text("stage2:\n  no_such_knob: 1\n")
    cmd = [sys.executable, "-m", "deepcrashtest.cli", "scenario", "build", str(raw), "-o", str(tmp_path / "s.json")]
    proc = subprocess.run([*cmd, "--config", str(cfg)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "no_such_knob" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "s.json").exists()
    cfg.write_text("stage2:\n  stepback_accel_mps2: 2.0\n")
    proc = subprocess.run([*cmd, "--config", str(cfg), "--json"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    out = json.loads((tmp_path / "s.json").read_text())
    assert out["provenance"]["parameters"]["stage2"]["stepback_accel_mps2"] == 2.0
