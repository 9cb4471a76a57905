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
