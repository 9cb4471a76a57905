"""The search on a real KITTI drive with one real oncoming car shifted to meet the ego (a head-on crash).

Everything runs through the real simulator; the checks re-simulate what the search reports
(safe variants, the boundary, the shrunk CEM variant) instead of trusting it.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from deepcrashtest.errors import UserError

sim = pytest.importorskip("deepcrashtest.sim")
if not hasattr(sim, "simulate_batch"):
    pytest.skip("the simulator (deepcrashtest.sim.simulate_batch) is not in this build", allow_module_level=True)

from deepcrashtest.scenario import Scenario  # noqa: E402
from deepcrashtest.search.evaluate import IN_PROCESS_WORK, Evaluator  # noqa: E402
from deepcrashtest.search.methods import is_safe  # noqa: E402
from deepcrashtest.search.run import SearchConfig, run_search  # noqa: E402
from deepcrashtest.search.space import SearchSpace  # noqa: E402
from deepcrashtest.sim.testcases import meet_ego  # noqa: E402

DURATION = 10.0  # s: the injected crash happens at ~8.7 s
SMALL = SearchConfig(
    starts=8, noise_variants=2, cem_budget=32, boundary_directions=8, duration=DURATION, video=False, max_scenarios=4
)


@pytest.fixture(scope="module")
def crash(kitti8_raw):
    """KITTI 0008 with the oncoming car 10 (observed 7.9-9.7 s) meeting the ego front to front at t = 8.8 s."""
    return meet_ego(kitti8_raw, 10, 8.8)


@pytest.fixture(scope="module")
def searched(crash, tmp_path_factory):
    out = tmp_path_factory.mktemp("search")
    return out, run_search(crash, out, SMALL)


def test_results_csv_one_row_per_simulated_variant(searched):
    out, summary = searched
    df = pd.read_csv(out / "results.csv")
    counts = df["method"].value_counts().to_dict()
    assert counts == {"original": 1, "random": 16, "cem": 32, "boundary": 8 * 7}
    assert summary["simulations"] == len(df)
    orig = df[df["method"] == "original"].iloc[0]
    assert orig["collided"] and orig["robustness"] <= 0 and summary["original"]["collided"]
    assert {"d_lon", "d_lat", "ex_1", "ey_1", "change_m", "robustness", "min_ttc", "delta_v_ego"} <= set(df.columns)
    # robustness is a signed separation: <= 0 exactly on collision; safe = no collision
    assert (df.loc[df["collided"], "robustness"] <= 0).all() and (df.loc[~df["collided"], "robustness"] > 0).all()
    assert (df["safe"] == ~df["collided"]).all()
    r = df[df["method"] == "random"]
    assert (r["d_lon"].abs() <= 4).all() and (r["d_lat"].abs() <= 2).all()
    for m in ("random", "cem", "boundary"):
        d = df[df["method"] == m].reset_index()
        hits = d.index[d["safe"]]
        expected = int(hits[0]) + 1 if len(hits) else None
        assert summary["methods"][m]["first_safe_at"] == expected
        assert summary["methods"][m]["safe"] == int(d["safe"].sum())
    assert json.loads((out / "summary.json").read_text()) == json.loads(json.dumps(summary))
    assert (out / "starts.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_safe_variant_files_replay_safe_in_the_simulator(searched, crash):
    out, summary = searched
    df = pd.read_csv(out / "results.csv").set_index("variant")
    files = summary["outputs"]["safe_scenarios"]
    assert 1 <= len(files) <= 4
    for f in files[:2]:
        sc = Scenario.load(f)
        p = sc.provenance
        vid = p.parameters["variant"]
        assert p.command == "search" and p.seed == 0 and p.parameters["controller"] == "replay"
        assert df.loc[vid, "safe"]
        assert p.parameters["d_lon_m"] == pytest.approx(df.loc[vid, "d_lon"], abs=1e-5)
        assert sc.collision is None and sc.agents == crash.agents
        start = np.array([sc.ego.trajectory.x[0], sc.ego.trajectory.y[0]])
        c, s = np.cos(crash.ego.trajectory.yaw[0]), np.sin(crash.ego.trajectory.yaw[0])
        d_lon, d_lat = df.loc[vid, "d_lon"], df.loc[vid, "d_lat"]
        assert np.allclose(start, [c * d_lon - s * d_lat, s * d_lon + c * d_lat], atol=0.1)
        res = sim.simulate(sc, duration=DURATION)
        assert not res.metrics["collided"], (vid, res.metrics)
        assert res.metrics["robustness"] == pytest.approx(df.loc[vid, "robustness"], abs=0.15)


def test_boundary_rays_are_safe_outside_and_unsafe_inside(searched, crash):
    _, summary = searched
    b = summary["boundary"]
    space = SearchSpace.for_scenario(crash)
    rows = []
    for a, r in zip(b["angle_deg"], b["radius_m"], strict=True):
        if r is None:
            continue
        u = np.array([np.cos(np.radians(a)), np.sin(np.radians(a))])
        for rr in (r, r - 0.1):  # bisection resolution: box edge / 2**6 <= 0.07 m
            th = np.zeros(space.dim)
            th[:2] = rr * u
            rows.append(th)
    assert rows, b
    with Evaluator(crash, space, duration=DURATION) as ev:
        safe = is_safe(ev(np.array(rows)))
    assert safe[0::2].all() and not safe[1::2].any()
    # straight left/right of the original start the boundary is where the boxes stop overlapping:
    # half the ego's width plus half the (oncoming, nearly anti-parallel) agent's width
    half_widths = (crash.ego.width + crash.vehicle(10).width) / 2
    for angle in (90.0, 270.0):
        r = b["radius_m"][b["angle_deg"].index(angle)]
        assert r is not None and abs(r - half_widths) < 0.35, (angle, r, half_widths)


def test_cem_shrinks_its_best_variant_to_the_boundary(searched, crash):
    out, summary = searched
    df = pd.read_csv(out / "results.csv")
    cem = df[df["method"] == "cem"]
    best = cem[cem["safe"]].sort_values("change_m").iloc[0]
    assert summary["methods"]["cem"]["best_change_m"] == pytest.approx(best["change_m"], abs=1e-4)
    space = SearchSpace.for_scenario(crash)
    theta = best[space.names()].to_numpy(dtype=float)
    with Evaluator(crash, space, duration=DURATION) as ev:
        res = ev(np.vstack([theta, 0.85 * theta]))
    assert is_safe(res).tolist() == [True, False]


def test_same_seed_same_results_and_engines_agree(crash, tmp_path):
    space = SearchSpace.for_scenario(crash)
    theta = space.reference_grid(np.random.default_rng(3), 12, 2)
    outs = {}
    pools = {}
    for name, workers, work in (("inline", 1, IN_PROCESS_WORK), ("pool", 2, 0), ("small", 2, IN_PROCESS_WORK)):
        with Evaluator(crash, space, workers=workers, duration=DURATION, chunk=8, in_process_work=work) as ev:
            outs[name] = ev(theta)
            pools[name] = ev._pool is not None
    # 24 variants are too little work for the pool unless told otherwise: the same chunks, in this process
    assert pools == {"inline": False, "pool": True, "small": False}
    for name, o in outs.items():
        for k, v in o.items():
            np.testing.assert_array_equal(v, outs["inline"][k], err_msg=f"{name}: {k}")
    assert outs["inline"]["collided"].any() and not outs["inline"]["collided"].all()
    cfg = SearchConfig(starts=4, noise_variants=2, method="random", duration=DURATION, video=False, max_scenarios=0)
    a = run_search(crash, tmp_path / "a", cfg)
    b = run_search(crash, tmp_path / "b", cfg)
    run_search(crash, tmp_path / "c", SearchConfig(**{**cfg.__dict__, "seed": 1}))
    assert a["methods"] == b["methods"]
    assert (tmp_path / "a" / "results.csv").read_bytes() == (tmp_path / "b" / "results.csv").read_bytes()
    assert (tmp_path / "a" / "results.csv").read_bytes() != (tmp_path / "c" / "results.csv").read_bytes()


@pytest.mark.skipif(
    not __import__("importlib").util.find_spec("ray"), reason="ray is not installed (pip install deepcrashtest[ray])"
)
def test_ray_engine_runs_a_whole_search(crash, tmp_path):
    import ray

    space = SearchSpace.for_scenario(crash)
    theta = space.reference_grid(np.random.default_rng(3), 12, 2)
    with Evaluator(crash, space, duration=DURATION, chunk=8) as ev:
        inline = ev(theta)
    with Evaluator(crash, space, engine="ray", workers=2, duration=DURATION, chunk=8) as ev:
        chunks_on_ray = ev(theta)  # 3 chunks as Ray tasks
    for k, v in inline.items():
        np.testing.assert_array_equal(chunks_on_ray[k], v, err_msg=k)
    cfg = SearchConfig(starts=4, noise_variants=2, method="random", duration=DURATION, video=False, max_scenarios=0)
    local = run_search(crash, tmp_path / "local", cfg)
    on_ray = run_search(crash, tmp_path / "ray", cfg, engine="ray", workers=2)
    ray.shutdown()
    assert on_ray["engine"] == "ray" and local["methods"] == on_ray["methods"]
    assert (tmp_path / "local" / "results.csv").read_bytes() == (tmp_path / "ray" / "results.csv").read_bytes()


def test_refuses_to_overwrite_and_bad_settings(searched, crash):
    out, _ = searched
    with pytest.raises(UserError, match="already exists"):
        run_search(crash, out, SMALL)
    with pytest.raises(UserError, match="--method"):
        run_search(crash, out, SearchConfig(method="genetic"))
    with pytest.raises(UserError, match="--engine"):
        Evaluator(crash, SearchSpace.for_scenario(crash), engine="spark")


def test_cli_search_json(crash, tmp_path):
    path = crash.save(tmp_path / "crash.json")
    args = [sys.executable, "-m", "deepcrashtest.cli", "search", str(path), "-o", str(tmp_path / "out")]
    small = ["--starts", "4", "--noise-variants", "2", "--method", "random", "--duration", "10", "--no-video"]
    proc = subprocess.run([*args, *small, "--json"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    assert s["methods"]["random"]["simulations"] == 8 and s["original"]["collided"] is True
    again = subprocess.run([*args, *small], capture_output=True, text=True, timeout=300)
    assert again.returncode == 2 and "already exists" in again.stderr and len(again.stderr.splitlines()) == 1
    bad = subprocess.run([*args, "--method", "genetic", "--force"], capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and "--method" in bad.stderr


def test_results_csv_text_is_pandas_to_csv(searched):
    from deepcrashtest.search.table import csv_text

    out, _ = searched
    df = pd.read_csv(out / "results.csv")
    df.loc[0, "min_ttc"] = np.inf
    assert csv_text(df) == df.to_csv(index=False, float_format="%.6g")
    for fmt in ("%.3f", "%+.2e", "%.3f m"):  # one row format per line; a format of more than one conversion: per cell
        assert csv_text(df, fmt) == df.to_csv(index=False, float_format=fmt)
    df["method"] = df["method"].astype(object)
    df.loc[1, "method"] = 'a "quoted", name'  # needs quoting: pandas writes it
    assert csv_text(df) == df.to_csv(index=False, float_format="%.6g")
