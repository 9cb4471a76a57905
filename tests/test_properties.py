"""Property-based tests (Hypothesis) of issue 18: Scenario loading, stage 2 and the simulator never end in an
internal error. A few hundred examples here (``DCT_FUZZ_EXAMPLES`` per property, derandomised so CI is
repeatable); ``bench/fuzz_scenarios.py`` runs 10,000."""

from __future__ import annotations

import json
import os

from hypothesis import HealthCheck, Phase, given, settings

from deepcrashtest.trajectory.pipeline import process_scenario
from scenario_strategies import (
    load_or_refuse,
    mutated_dicts,
    process_or_refuse,
    scenario_dicts,
    simulate_or_refuse,
)
from trajectory_cases import CLASS_CASES, raw_scenario

EXAMPLES = int(os.environ.get("DCT_FUZZ_EXAMPLES", "80"))
FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None,
    derandomize=True,
    phases=(Phase.explicit, Phase.reuse, Phase.generate),  # no shrinking: a failure prints its whole input
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
BASE = json.loads(process_scenario(raw_scenario([CLASS_CASES["D0T1"], CLASS_CASES["D1T1"]])).to_json())


@FUZZ
@given(mutated_dicts(BASE))
def test_any_file_loads_or_is_refused_clearly(data):
    """Arbitrary edits of a real file: a Scenario (that simulates) or a ScenarioError."""
    sc = load_or_refuse(data)
    if sc is not None:
        simulate_or_refuse(sc)


@FUZZ
@given(scenario_dicts("processed"))
def test_schema_valid_processed_scenarios_simulate_or_refuse_clearly(data):
    sc = load_or_refuse(data)
    if sc is not None:
        simulate_or_refuse(sc)


@FUZZ
@given(scenario_dicts("raw"))
def test_schema_valid_raw_scenarios_process_and_simulate_or_refuse_clearly(data):
    raw = load_or_refuse(data)
    if raw is None:
        return
    sc = process_or_refuse(raw)
    if sc is not None:
        simulate_or_refuse(sc)


def test_a_path_of_thousands_of_kilometres_is_refused_not_resampled():
    """A schema-valid agent jumping ~100 km between samples (found by the property above, which then
    asked for 24 GB): a clear refusal naming the vehicle, not millions of path points."""
    import pytest

    from deepcrashtest.errors import ScenarioError
    from deepcrashtest.scenario import Scenario
    from deepcrashtest.sim import simulate

    data = json.loads(json.dumps(BASE))
    traj = data["agents"][0]["trajectory"]
    traj["x"] = [x + (95_000.0 if k % 2 else 0.0) for k, x in enumerate(traj["x"])]
    sc = Scenario.from_dict(data, origin="test")
    with pytest.raises(ScenarioError, match=f"vehicle {sc.agents[0].id}: a path of .* km"):
        simulate(sc, duration=min(sc.duration(), 4.0))


def test_cli_commands_after_extraction_on_fuzzed_scenarios(tmp_path):
    """bench/fuzz_cli.py in small (seeded): a few schema-valid odd scenarios, processed and raw, through every
    command after extraction (validate, build, simulate, search, export x3, report, fidelity): exit 0 or one
    line with exit 2, never an internal error."""
    import importlib.util
    from pathlib import Path

    bench = Path(__file__).resolve().parents[1] / "bench" / "fuzz_cli.py"
    spec = importlib.util.spec_from_file_location("fuzz_cli", bench)
    assert spec is not None and spec.loader is not None
    fuzz_cli = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fuzz_cli)
    fz = fuzz_cli.Fuzz()
    examples = int(os.environ.get("DCT_FUZZ_CLI_EXAMPLES", "4"))
    counts = fuzz_cli.part_scenarios(fz, examples, 0, tmp_path, None)
    assert counts == {"processed": examples // 2, "raw": examples // 2}
    assert fz.failures == []
    assert fz.codes[0] > 0  # some commands ran to the end, not only refusals
