"""The crash the video shows happens in the replay too (``pipeline.stage2.processed_scenario``): where the replay of
stage 2's result misses the crash pair's contact, stage 2 runs again with the pair overlapping longer after it (real
clip: ccd_001135, the ego crawling round a right turn when a car spinning on a wet road hits its front)."""

from __future__ import annotations

from pathlib import Path

import pytest

from conftest import DATA, need
from deepcrashtest.scenario import Scenario


@pytest.fixture(scope="module")
def ccd1135(tmp_path_factory: pytest.TempPathFactory, yolo_ok) -> Scenario:
    """The raw scenario of ccd_001135's extraction, as a user would run it (without lanes and report)."""
    from deepcrashtest.pipeline.extract import run_extract

    out: Path = tmp_path_factory.mktemp("ccd1135")
    run_extract(need(DATA / "crash_ccd" / "ccd_001135.mp4"), out, lanes=False, report=False, annotate=False)
    return Scenario.load(out / "scenario_raw.json")


def test_a_crash_the_replay_misses_is_made_again_with_a_longer_overlap(ccd1135):
    """The ego's replay (its vehicle model's path follower holds the front axle on the path, so the centre runs
    inside the bend) misses the grazing contact when the pair overlaps only 0.02 s after its first touch; the
    pipeline's stage 2 sees that in one replay and makes the crash again with 0.2 s: the replay touches, the
    scenario says so. Where the replay touches at once, the result is stage 2's own."""
    from deepcrashtest.pipeline.stage2 import processed_scenario
    from deepcrashtest.sim import simulate
    from deepcrashtest.trajectory.params import Stage2Params
    from deepcrashtest.trajectory.pipeline import process_scenario

    short = Stage2Params(crash_overlap_s=0.02)
    plain = process_scenario(ccd1135, params=short)
    assert plain.collision is not None and set(plain.collision.participants) == {0, 1}
    assert simulate(plain).contact_between(0, 1) is None  # the replay misses it
    again = processed_scenario(ccd1135, params=short)
    assert again.collision is not None and set(again.collision.participants) == {0, 1}
    hit = simulate(again).contact_between(0, 1)
    assert hit is not None and abs(hit["time"] - again.collision.time_s) < 0.1
    assert "overlap 0.2 s after it" in again.warnings[-1]
    default = processed_scenario(ccd1135)
    assert simulate(default).contact_between(0, 1) is not None
    assert default.model_dump_json() == process_scenario(ccd1135).model_dump_json()
