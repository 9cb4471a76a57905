"""extract's skip of SciPy's import-time docstring rewriting: the functions and their results stay the same."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import DATA, need
from deepcrashtest.scipy_docs import PlainDoc

SRC = Path(__file__).resolve().parents[1] / "src"

#: In a fresh interpreter: (optionally) the stand-in, then SciPy's modules extract uses, run on a real signal
#: (the highway clip's frame brightness): results and docstrings.
PROBE = """
import json, sys
import numpy as np
if sys.argv[1] == "plain":
    from deepcrashtest.scipy_docs import plain_scipy_docs
    assert plain_scipy_docs()
import scipy.optimize, scipy.signal, scipy.stats
import scipy._lib._array_api as aa, scipy.stats._axis_nan_policy as anp
h = np.array(json.loads(sys.argv[2]))
out = {
    "savgol": scipy.signal.savgol_filter(h, 9, 2).tolist(),
    "ttest": float(scipy.stats.ttest_1samp(h, 0.0).pvalue),
    "lsq": scipy.optimize.least_squares(lambda p: h - p[0] - p[1] * np.arange(len(h)), [0.0, 0.0]).x.tolist(),
    "doc": scipy.stats.ttest_1samp.__doc__,
    "stand_in": [aa.FunctionDoc.__name__, anp.FunctionDoc.__name__],
}
print(json.dumps(out))
"""


def _probe(mode: str, brightness: list[float]) -> dict:
    env = {"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"}
    run = subprocess.run([sys.executable, "-c", PROBE, mode, json.dumps(brightness)], capture_output=True, env=env)
    assert run.returncode == 0, run.stderr.decode()[-2000:]
    return json.loads(run.stdout)


@pytest.fixture(scope="module")
def brightness() -> list[float]:
    import cv2

    cap = cv2.VideoCapture(str(need(DATA / "dashcam_udacity" / "highway_lane_challenge.mp4")))
    means = []
    for _ in range(40):  # a real signal: the mean brightness of the clip's first 40 frames
        ok, frame = cap.read()
        assert ok
        means.append(float(frame.mean()))
    cap.release()
    return means


def test_plain_docs_same_results_without_scipys_notes(brightness):
    plain, rewritten = _probe("plain", brightness), _probe("scipy", brightness)
    assert plain["stand_in"] == ["PlainDoc", "PlainDoc"] and rewritten["stand_in"] == ["FunctionDoc", "FunctionDoc"]
    for key in ("savgol", "ttest", "lsq"):
        assert plain[key] == rewritten[key]
    # SciPy's own rewriting adds its sections (e.g. the nan_policy parameter); the stand-in leaves the docstring
    assert "nan_policy" in rewritten["doc"] and plain["doc"] != rewritten["doc"]


def test_plain_doc_sections():
    def f() -> None:
        """Sum.

        Parameters
        ----------
        x : int
        """

    doc = PlainDoc(f)
    assert doc["Parameters"] == [] and doc["Notes"] == []
    doc["Notes"] += ["a note"]
    assert doc["Notes"] == ["a note"]
    assert str(doc).split("\n", 1)[1] == f.__doc__
