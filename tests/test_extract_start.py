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


def test_the_run_keeps_numpys_blas_on_one_thread(tmp_path, monkeypatch):
    """OpenBLAS's second thread spun and the main thread waited for it (``blas_thread_server`` / ``exec_blas``:
    ~5 % of the process CPU in ``perf``, stage 2's CPU 0.78 -> 0.33 s on the highway clip) for the run's small
    matrices: ``extract`` runs them on one thread and gives the caller's setting back."""
    from pathlib import Path

    from threadpoolctl import threadpool_info, threadpool_limits

    import deepcrashtest.pipeline.extract as ex

    seen: list[int] = []
    table = ex.records_table

    def spy(records):  # called on the main thread after the pass, inside the run
        seen.extend(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")
        return table(records)

    monkeypatch.setattr(ex, "records_table", spy)
    sample = Path(__file__).resolve().parents[1] / "examples" / "highway_sample.mp4"
    with threadpool_limits(limits=2, user_api="blas"):
        ex.run_extract(sample, tmp_path / "ex", max_frames=6, geometry=False, shots=False)
        after = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
    assert seen and set(seen) == {1}
    assert after and set(after) == {2}
