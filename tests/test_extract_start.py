"""What ``extract``'s main thread imports before its decoding pass starts (the rest loads in the background)."""

from __future__ import annotations

import subprocess
import sys


def test_the_pass_is_set_up_without_pandas_or_the_crash_detection():
    """pandas (~0.45 s of CPU) and the crash detection load in ``extract``'s background import thread while the first
    frames decode; setting up the pass (its global-motion measure included) must not import them on the main thread
    first (measured: main-thread CPU before the first frames 1.93-2.27 -> 1.34-1.58 s at load 9)."""
    code = (
        "import sys\nfrom pathlib import Path\nfrom deepcrashtest.pipeline.extract import _Pass\n"
        "plan = _Pass(Path('v.mp4'), Path('out'), {}, None, 5, None, None, False, None, 0)\n"
        "plan.motion.update(0, __import__('numpy').zeros((72, 128, 3), 'uint8'))\n"
        "print(sorted(m for m in ('pandas', 'scipy', 'deepcrashtest.perception.crash_detect') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "[]"
