"""Issue 18 fuzzing: 10,000 Hypothesis examples over Scenario loading, stage 2 and the simulator.

The properties are those of tests/test_properties.py (tests/scenario_strategies.py): any schema-valid scenario
or raw scenario processes and simulates or gives a clear error (UserError / ScenarioError), never an internal
one; arbitrary edits of a real file load or are refused with a ScenarioError. Prints one JSON line with the
examples run per property and the failures (0 is the goal).
Usage: python bench/fuzz_scenarios.py [--examples 10000] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "src"), str(ROOT / "tests")]

from hypothesis import HealthCheck, Phase, given, seed, settings  # noqa: E402

from deepcrashtest.trajectory.pipeline import process_scenario  # noqa: E402
from scenario_strategies import (  # noqa: E402
    load_or_refuse,
    mutated_dicts,
    process_or_refuse,
    scenario_dicts,
    simulate_or_refuse,
)
from trajectory_cases import CLASS_CASES, raw_scenario  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--examples", type=int, default=10_000, help="total over the three properties")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    per = max(1, args.examples // 3)
    base = json.loads(process_scenario(raw_scenario([CLASS_CASES["D0T1"], CLASS_CASES["D1T1"]])).to_json())
    counts = {"files": 0, "processed": 0, "raw": 0}
    ok = {"files": 0, "processed": 0, "raw": 0}
    cfg = settings(
        max_examples=per,
        deadline=None,
        database=None,
        phases=(Phase.generate,),
        suppress_health_check=list(HealthCheck),
    )

    @seed(args.seed)
    @cfg
    @given(mutated_dicts(base))
    def files(data: object) -> None:
        counts["files"] += 1
        sc = load_or_refuse(data)
        if sc is not None:
            ok["files"] += 1
            simulate_or_refuse(sc)

    @seed(args.seed)
    @cfg
    @given(scenario_dicts("processed"))
    def processed(data: object) -> None:
        counts["processed"] += 1
        sc = load_or_refuse(data)
        if sc is not None:
            ok["processed"] += 1
            simulate_or_refuse(sc)

    @seed(args.seed)
    @cfg
    @given(scenario_dicts("raw"))
    def raw(data: object) -> None:
        counts["raw"] += 1
        r = load_or_refuse(data)
        if r is not None:
            sc = process_or_refuse(r)
            if sc is not None:
                ok["raw"] += 1
                simulate_or_refuse(sc)

    failures: dict[str, str] = {}
    t0 = time.perf_counter()
    for name, prop in (("files", files), ("processed", processed), ("raw", raw)):
        try:
            prop()
        except Exception as exc:  # a property failed: an internal error (the input is in the message)
            failures[name] = f"{type(exc).__name__}: {str(exc)[-2000:]}"
            traceback.print_exc(limit=3)
    print(
        json.dumps(
            {
                "examples": counts,
                "examples_total": sum(counts.values()),
                "valid_and_simulated": ok,
                "internal_errors": len(failures),
                "failures": failures,
                "seconds": round(time.perf_counter() - t0, 1),
            }
        )
    )
    if failures:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
