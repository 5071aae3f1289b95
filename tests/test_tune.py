"""``damper-hil tune``: the design space, the front and the sensitivity against independent
definitions, the evaluation against the single-design ride path, and the command end to
end on a real ``distributed.LocalCluster``."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import load_config, save_config
from ride_sim import tuning as tu
from ride_sim.dampers import CompressiblePlugin
from ride_sim.params import load_ride_config
from ride_sim.quarter_car import simulate
from ride_sim.study_runs import metrics, start_state


def _cli(*args: object) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "damper_hil.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=900)


def _brute_front(f: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Non-dominated rows by the definition, pair by pair."""
    out = np.zeros(len(f), bool)
    for i in range(len(f)):
        if not ok[i]:
            continue
        out[i] = not any(ok[j] and all(f[j] <= f[i]) and any(f[j] < f[i])
                         for j in range(len(f)) if j != i)
    return out


def test_pareto_mask_is_the_definition():
    rng = np.random.default_rng(4)
    for _ in range(20):
        f = rng.integers(0, 6, size=(40, 3)).astype(float)  # ties and duplicates
        ok = rng.random(40) > 0.2
        np.testing.assert_array_equal(tu.pareto_mask(f, ok), _brute_front(f, ok))
    # on the line x + y = 1 every point is on the front; a point above it is not
    pts = np.array([[0.0, 1.0], [0.5, 0.5], [1.0, 0.0], [0.6, 0.6]])
    assert tu.pareto_mask(pts).tolist() == [True, True, True, False]


def test_sensitivity_is_the_rank_correlation():
    rng = np.random.default_rng(0)
    x = np.exp(rng.uniform(-0.7, 0.7, size=(200, 3)))
    y = np.column_stack([x[:, 0] ** 3, -np.log(x[:, 1]), rng.random(200)])
    rho = tu.sensitivity(x, y)
    assert rho.shape == (3, 3)
    assert rho[0, 0] == pytest.approx(1.0) and rho[1, 1] == pytest.approx(-1.0)
    assert abs(rho[2, 2]) < 0.2 and abs(rho[2, 0]) < 0.2  # unrelated: near 0


def test_design_config_scales_exactly_the_tuned_constants(sport_cfg):
    spec = tu.spec_from_mapping(None, "test")
    same = tu.design_config(sport_cfg, np.ones(len(spec.variables)), spec)
    assert same.damper == sport_cfg.damper
    f = np.ones(len(spec.variables))
    f[spec.variables.index("rebound_k_leak")] = 2.0
    f[spec.variables.index("compression_preload_pa")] = 0.5
    cfg = tu.design_config(sport_cfg, f, spec)
    d, b = cfg.damper, sport_cfg.damper
    assert d.rebound.k_leak == 2.0 * b.rebound.k_leak
    assert d.compression.preload_pa == 0.5 * b.compression.preload_pa
    assert (d.rebound.k_port, d.gas_pressure_static_pa) == (b.rebound.k_port,
                                                            b.gas_pressure_static_pa)
    # the factors span the bounds log-uniformly: the cube's centre is the geometric mean
    centre = tu.factors_of(np.full((1, len(spec.variables)), 0.5), spec)
    np.testing.assert_allclose(centre, 1.0, rtol=1e-12)


def test_the_settings_file_holds_the_schema_defaults():
    from damper_emulator.schema import read_yaml
    from damper_hil.param_reference import REPO

    path = REPO / "config" / "tune.yaml"
    assert tu.spec_from_mapping(read_yaml(path), str(path)) == tu.TuneSpec()
    assert tu.spec_from_mapping(read_yaml(path), str(path), designs=1000).settings.designs \
        == 1000


def test_sobol_design_is_space_filling():
    u = tu.sobol(64, 8, seed=1)
    assert u.shape == (64, 8) and u.min() >= 0 and u.max() < 1
    # a scrambled Sobol sequence of 2^6 points puts one point in each 1/64 of every axis
    for k in range(8):
        assert len(np.unique(np.floor(u[:, k] * 64))) == 64


def test_evaluation_equals_the_single_design_path(sport_cfg):
    rc = load_ride_config()
    dt = rc.simulation.step_s
    spec = tu.spec_from_mapping({"tune": {"road_classes": "B", "length_m": 100.0,
                                          "pothole": False}}, "test")
    roads = tu.roads(spec.settings, rc.road, dt)
    f = np.vstack([np.ones(8), np.full(8, 0.7)])
    ev = tu.evaluate(sport_cfg, f, spec, rc.quarter_car, roads, dt)
    r = roads[0]
    for j in range(2):
        model = DamperModel(tu.design_config(sport_cfg, f[j], spec))
        one = simulate(rc.quarter_car, CompressiblePlugin(model), r.heights, dt,
                       initial_state=start_state(r.heights, dt))
        m = metrics(one, r.start, r.stop)
        for k, (name, _, _) in enumerate(tu.OBJECTIVES):
            assert ev[j, k] == pytest.approx(m[name], rel=1e-9)
        assert ev[j, tu.EVAL_COLUMNS.index("sws_peak_bump")] == pytest.approx(
            one.sws_m[r.start:r.stop].max(), rel=1e-9)
    # softer valves (every constant x0.7) do give a different ride
    assert abs(ev[1, 0] / ev[0, 0] - 1) > 0.01


def test_a_design_the_damper_rules_refuse_is_infeasible_not_an_error(sport_cfg):
    rc = load_ride_config()
    spec = tu.spec_from_mapping({"tune": {"bypass": True, "road_classes": "A",
                                          "length_m": 100.0, "pothole": False}}, "test")
    f = np.ones((2, len(spec.variables)))
    f[1, spec.variables.index("normal_bypass_diameter_m")] = 2.0  # wider than comfort
    f[1, spec.variables.index("comfort_bypass_diameter_m")] = 0.5
    roads = tu.roads(spec.settings, rc.road, rc.simulation.step_s)
    ev = tu.evaluate(sport_cfg, f, spec, rc.quarter_car, roads, rc.simulation.step_s)
    assert ev[0, tu.EVAL_COLUMNS.index("feasible")] == 1.0
    assert ev[1, tu.EVAL_COLUMNS.index("feasible")] == 0.0 and np.isnan(ev[1, 0])
    assert not tu.pareto_mask(ev[:, :3], ev[:, -1] > 0.5)[1]


@pytest.mark.slow
def test_tune_end_to_end_on_a_local_cluster(tmp_path):
    out = tmp_path / "out"
    res = _cli("tune", "--out", out, "--designs", 16, "--refine-rounds", 1,
               "--refine-designs", 8, "--length", 100, "--road-classes", "A,B",
               "--chunk", 6, "--workers", 2)
    assert res.returncode == 0, res.stderr
    assert "local Dask cluster, 2 worker processes" in res.stderr
    doc = json.loads((out / "pareto.json").read_text())
    assert doc["evaluated"] == 1 + 16 + 8
    with (out / "designs.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 25 and sum(int(r["pareto"]) for r in rows) == len(doc["designs"])
    # every front design is non-dominated among the feasible designs of designs.csv
    names = [n for n, _, _ in tu.OBJECTIVES]
    f = np.array([[float(r[n]) for n in names] for r in rows])
    ok = np.array([float(r["feasible"]) > 0.5 for r in rows])
    front_ids = {r["id"] for r, m in zip(rows, _brute_front(f, ok)) if m}
    assert front_ids == {d["id"] for d in doc["designs"]}
    base = load_config()
    for d in doc["designs"]:
        assert set(d["objectives"]) == set(names)
        if d["id"] == "baseline":
            continue
        cfg = load_config(out / d["params_file"])  # loadable as every command loads it
        assert cfg.damper.rebound.k_leak == pytest.approx(
            base.damper.rebound.k_leak * d["factors"]["rebound_k_leak"], rel=1e-9)
    for name in ("balanced", "comfort", "road_holding"):
        assert load_config(out / f"chosen_{name}.yaml").damper.name == base.damper.name
    for png in ("pareto.png", "fourteen_speed.png", "sensitivity.png"):
        assert (out / png).stat().st_size > 10_000
    ranking = doc["sensitivity"]["accel_w_rms"]
    assert len(ranking) == 8 and abs(ranking[0]["spearman"]) >= abs(ranking[-1]["spearman"])
    # the chosen design loads in the virtual dyno as it is
    dyno = _cli("dyno", "--params", out / "chosen_balanced.yaml", "--protocol", "sine",
                "--frequency", 1, "--amplitude", 0.02, "--out", tmp_path / "dyno")
    assert dyno.returncode == 0, dyno.stderr


@pytest.mark.parametrize(("args", "needle"), [
    (["--road-classes", "Z"], "ISO 8608 class"),
    (["--bypass", "--params", "PASSIVE"], "damper.adaptive"),
    (["--designs", "0"], "--designs"),
])
def test_bad_settings_are_one_line(tmp_path, cli, args, needle):
    import dataclasses

    passive = tmp_path / "passive.yaml"
    cfg = load_config()
    save_config(dataclasses.replace(cfg, damper=dataclasses.replace(cfg.damper,
                                                                    adaptive=None)), passive)
    args = [passive if a == "PASSIVE" else a for a in args]
    res = cli("tune", "--out", tmp_path / "o", "--workers", 1, *args)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    # one line (an option's bad value: argparse's usage, then the one line)
    assert "error:" in lines[-1] and needle in lines[-1]
    assert len(lines) == 1 or lines[0].startswith("usage:")


def test_a_settings_file_with_an_unknown_key_is_one_line(tmp_path, cli):
    bad = tmp_path / "tune.yaml"
    bad.write_text("tune:\n  desings: 10\n")
    res = cli("tune", "--out", tmp_path / "o", "--settings", bad, "--workers", 1)
    assert res.returncode == 2 and "unknown parameter tune.desings" in res.stderr
    assert res.stderr.strip().count("\n") == 0
