"""A search's variant files on a real KITTI drive: a variant whose ego path asks more acceleration than any vehicle
has is refused with the Scenario's own message, found without validating the whole scenario."""

from __future__ import annotations

import numpy as np
import pytest

from deepcrashtest.errors import ScenarioError
from deepcrashtest.scenario import Scenario
from deepcrashtest.search.outputs import SharedAgentsJson, variant_scenario
from deepcrashtest.search.space import SearchSpace


def _refusal(fn) -> str:
    with pytest.raises(ScenarioError) as exc:
        fn()
    return str(exc.value)


@pytest.mark.parametrize("long_name", [False, True])
def test_jerky_variant_refused_with_the_scenarios_own_message(kitti8_raw, long_name):
    # processed (the physics checked), without the raw agents (some of their label tracks jump above the limit)
    name = "k" * 190 if long_name else kitti8_raw.name
    sc: Scenario = kitti8_raw.evolve(stage="processed", name=name, agents=[], collision=None)
    space = SearchSpace.for_scenario(sc)
    rng = np.random.default_rng(3)
    found = 0
    for _ in range(40):
        theta = np.concatenate([[0.0, 0.0], rng.normal(0.0, 3.0, space.dim - 2)])
        traj = space.variant_trajectory(theta)
        if traj.accel_problem("ego") is None or traj.speed and max(traj.speed) > 60:
            continue
        ego = sc.ego.model_copy(update={"trajectory": traj, "spline": space.variant_spline(theta)})
        # what validating the whole variant scenario says (the name too long for a file name when long_name)
        whole = _refusal(lambda ego=ego: sc.evolve(name=f"{sc.name}_variant0007", ego=ego)).removeprefix("scenario: ")
        got = _refusal(lambda theta=theta: variant_scenario(sc, space, theta, 7, {"seed": 0}))
        assert got == f"variant 7: {whole}"
        assert ("acceleration" in got) != long_name  # a name error comes first, as the whole validation says
        found += 1
    assert found >= 3


def test_raw_scenario_keeps_a_jerky_variant(kitti8_raw):
    """A raw scenario has no physics check: the same kind of variant is written, as the whole validation allows."""
    sc = kitti8_raw.evolve(stage="raw", agents=[], collision=None)
    space = SearchSpace.for_scenario(sc)
    rng = np.random.default_rng(3)
    jerky = [
        th
        for th in (np.concatenate([[0.0, 0.0], rng.normal(0.0, 3.0, space.dim - 2)]) for _ in range(40))
        if space.variant_trajectory(th).accel_problem("ego") is not None
        and max(space.variant_trajectory(th).speed) < 60
    ]
    assert jerky
    assert variant_scenario(sc, space, jerky[0], 7, {"seed": 0}).stage == "raw"


def test_variant_file_text_is_the_scenarios_own_json(kitti8_raw):
    """The variant files' text with the agents serialised once is ``Scenario.to_json()`` character for character
    (KITTI 0008, a search variant and a scenario without them); with other agents it is serialised whole."""
    sc = kitti8_raw.evolve(name="k8")
    texts = SharedAgentsJson(sc)
    assert texts.fragment is not None and texts.fragment.startswith("[")
    space = SearchSpace.for_scenario(sc)
    theta = np.concatenate([[1.0, -0.5], np.full(space.dim - 2, 0.1)])
    variant = variant_scenario(sc, space, theta, 3, {"seed": 0})
    assert variant.agents[0] is sc.agents[0]
    assert texts.text(variant) == variant.to_json()
    fewer = variant.evolve(agents=variant.agents[1:])
    assert texts.text(fewer) == fewer.to_json()
    none = SharedAgentsJson(sc.evolve(agents=[], collision=None))
    alone = variant.evolve(agents=[], collision=None)
    assert none.fragment == "[]" and none.text(alone) == alone.to_json()
