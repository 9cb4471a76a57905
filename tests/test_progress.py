"""Progress bars: on stderr when it is a terminal, silent with --json or without a terminal."""

from __future__ import annotations

import os
import pty
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import ROOT

CLIP = ROOT / "examples" / "highway_sample.mp4"


def _extract(tmp_path: Path, *extra: str, terminal: bool) -> tuple[str, str]:
    """Run ``deepcrashtest extract`` on 6 frames; stderr is a pseudo-terminal when ``terminal``."""
    cmd = [sys.executable, "-m", "deepcrashtest.cli", "extract", str(CLIP)]
    cmd += ["-o", str(tmp_path / "o"), "--max-frames", "6", "--no-geometry", "--force", *extra]
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"), COLUMNS="100")
    if not terminal:
        done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        return done.stdout, done.stderr
    main, sub = pty.openpty()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=sub, text=True)
    os.close(sub)
    chunks = []
    while True:
        try:
            data = os.read(main, 4096)
        except OSError:  # the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    out = proc.stdout.read()  # type: ignore[union-attr]
    assert proc.wait(timeout=300) == 0
    os.close(main)
    return out, b"".join(chunks).decode(errors="replace")


@pytest.mark.skipif(not CLIP.exists(), reason="examples/highway_sample.mp4 missing")
def test_extract_progress_bar_only_on_a_terminal_without_json(tmp_path):
    _, err = _extract(tmp_path, terminal=True)
    assert "extract" in err and "6/6" in err  # the bar: description, frames done of the total
    assert "writing the tracks" in err  # what runs after the frames: a spinner with its time
    out, err = _extract(tmp_path, "--json", terminal=True)
    assert "extract" not in err and "writing" not in err and out.lstrip().startswith("{")
    _, err = _extract(tmp_path, terminal=False)
    assert "extract" not in err and "writing" not in err
