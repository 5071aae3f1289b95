"""``diagnose`` as a user runs it: ``identify`` on the truth data's quasi-static and chirp
files with the damper's data sheet, then ``diagnose`` on the same files with the sines
held out.  The truth differs in model form from the emulator's model (smooth friction, a
4× finer integrator, displacement noise; ``truth.REALISTIC``) and carries effects the
identification never heard of: they must come back by family, with the held-out residual
brought down to the floor; data without one as ``none`` (on two dampers); two effects
together as both (effects outside the library, found by the term discovery:
``test_diagnose_discovery.py``).

The suite uses a shorter protocol and, for the single effects, the true candidate among
two that are easily confused with it (the full protocol with all nine candidates:
``benchmarks/diagnose_bench.py``)."""

from __future__ import annotations

import json
import math
import multiprocessing
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest
from diagnose_support import (
    FEW_NFEV,
    NOISE_N,
    PARAMETER_TOLERANCE,
    PROTOCOL,
    identify_and_diagnose,
    pooled,
    truth_session,
)

from damper_emulator.diagnose.outcome import (
    FLOOR_FORCE_FRACTION,
    MIN_SCORE,
    noise_level,
    structure_ratio,
)
from damper_emulator.diagnose.report import markdown, named_from, write_report
from damper_emulator.diagnose.selection import diagnose, weigh_effects
from damper_emulator.diagnose.truth import (
    EXAMPLE_EFFECTS,
    REALISTIC,
    example_config,
    simulate_session,
    write_session,
)
from damper_emulator.identify.pipeline import identify
from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import EXTENSION_FAMILIES, load_config, save_config
from damper_hil.cli import main

pytestmark = pytest.mark.slow


@pytest.mark.parametrize(("damper", "effects"), [
    ("sport", None),
    ("van", ["lugre_friction", "valve_lag", "series_compliance", "end_stops"])])
def test_without_an_extra_effect_the_answer_is_none_on_two_dampers(damper, effects):
    """No extension in the truth, only its model-form differences: all nine candidates
    (on the van, the four that took most of a noise-only residual in the benchmark) are
    tried and none is significant."""
    sheet, data = truth_session(None, damper)
    diag = identify_and_diagnose(sheet, data, effects)
    assert diag.family == "none" and diag.effect is None and not diag.significant, [
        (c.candidate.effect, c.score, c.delta_bic) for c in diag.ranking]
    assert not diag.steps and all(not c.significant for c in diag.ranking)
    # the refitted paper's model is within the floor, which is what `none` says
    refit = pooled(diag.refit.rms_held_out, diag.held_out)
    assert refit <= diag.floor_n
    # the floor is at least 1 % of the held-out force r.m.s. (the counted samples)
    force = np.concatenate([r.data.force[r.start:] for r in diag.records if r.held_out])
    assert diag.floor_n >= FLOOR_FORCE_FRACTION * float(np.sqrt(np.mean(force ** 2))) - 1e-9
    assert diag.to_json()["effects"] == []
    # no cavity worth the friction search (four re-identifications) on these dampers
    assert all(f["friction_factor"] is None for f in diag.to_json()["rounds"][0])


def test_two_effects_together_are_both_found_by_forward_selection():
    pair = ("lugre_friction", "valve_lag")
    sheet, data = truth_session(pair)
    diag = identify_and_diagnose(sheet, data, [*pair, "series_compliance"])
    assert {s.candidate.effect for s in diag.steps} == set(pair), diag.to_json()["rounds"]
    doc = diag.to_json()
    assert doc["effect"] == doc["effects"][0]["effect"]
    assert [e["effect"] for e in doc["effects"]] == [s.candidate.effect for s in diag.steps]
    assert all(e["held_out_gain"] >= MIN_SCORE for e in doc["effects"])
    # the model after carries both effects, with the fitted values the JSON reports
    active = diag.model_after().cfg.damper.extensions.active()
    assert sorted(active) == sorted(pair)
    after = pooled(diag.rms_after, diag.held_out)
    assert after <= max(diag.floor_n, 2.0 * NOISE_N)
    # the first effect tried away once the search ended: both are in the truth, it stays
    (tried,) = doc["pruned"]
    assert tried["effect"] == diag.steps[0]._added.effect and not tried["went"]
    assert tried["held_out_gain"] >= MIN_SCORE
    assert pooled(tried["rms_held_out_without"], diag.held_out) > after
    assert f"- {tried['effect']} ({tried['family']}): " in markdown(diag)


def test_an_effect_the_first_one_masked_is_found_on_top_of_it_from_the_better_order():
    """Free air in the oil beside a gas that exchanges heat: alone, each gains about as
    much held out, and round 1 adds the heat transfer.  Round 2 fits the air on top of
    it.  Started from the air's own round-1 fit with the heat transfer pre-fitted on it
    (the other order, the lower pre-fit), the joint fit stays in the air's valley and
    loses the heat transfer's part (there the air gained −0.6 %, and the answer was
    `other`); from the forward order too, the better end kept, both stay."""
    truth = ("air_entrainment", "gas_heat_transfer")
    sheet, data = truth_session(truth)
    diag = identify_and_diagnose(sheet, data,
                                 ["gas_heat_transfer", "lugre_friction", "air_entrainment"],
                                 discovery=False)
    doc = diag.to_json()
    assert sorted(s.candidate.effect for s in diag.steps) == sorted(truth), doc["rounds"]
    assert all(e["held_out_gain"] >= MIN_SCORE for e in doc["effects"])
    assert pooled(diag.rms_after, diag.held_out) <= max(diag.floor_n, 2.0 * NOISE_N)


def test_two_effects_the_identification_files_confound_are_found_as_a_pair():
    """A bypass groove and the oil's viscosity–temperature law: the chirp heats up as its
    frequency rises, so the identified valves absorb both.  Alone, the groove fits the
    identification files far better but worsens the hotter held-out sines, and the
    temperature law hardly moves: nothing is significant alone.  The pair search fits the
    groove (the most evidence on the identification files) with each other candidate and
    adds the pair, which takes the held-out residual to the floor."""
    pair = ("bypass_groove", "viscosity_temperature")
    sheet, data = truth_session(pair)
    diag = identify_and_diagnose(sheet, data, [*pair, "valve_lag"])
    assert not any(f.significant for f in diag.rounds[0]), diag.to_json()["rounds"]
    assert [s.candidate.effect for s in diag.steps] == list(pair), diag.to_json()["rounds"]
    assert diag.family == EXTENSION_FAMILIES["bypass_groove"]
    doc = diag.to_json()
    assert doc["pair_gain"] == doc["score"] == diag.pair_gain >= MIN_SCORE
    # the groove was not significant alone; the temperature law is, on top of it
    assert [e["significant"] for e in doc["effects"]] == [False, True]
    assert pooled(diag.rms_after, diag.held_out) <= max(diag.floor_n, 2.0 * NOISE_N)
    assert f"cuts the held-out r.m.s. by {100 * diag.pair_gain:.1f} %" in markdown(diag)
    fitted = {e["effect"]: e["parameters"] for e in doc["effects"]}
    for effect, names in (("bypass_groove", ("center_m", "half_length_m")),
                          ("viscosity_temperature", ("temperature_coefficient_per_k",))):
        for name in names:
            assert fitted[effect][name] == pytest.approx(
                EXAMPLE_EFFECTS[effect]["params"][name], rel=PARAMETER_TOLERANCE), fitted
    # a pair that explained too little would give `other`, with the pair's fit (both
    # effects, its gain against the refitted model) as the closest: here by demanding
    # more than all of the structured power
    held = [r for r in diag.records if r.held_out]
    ref_held = [r.residual(diag.refit.model()) for r in held]
    steps, closest, explained, gain = weigh_effects(
        diag.refit, ref_held, list(diag.steps), held, 0.0, diag.pair_gain,
        min_explained=1.0, structure=0.0)
    assert steps == [] and gain is None and explained == pytest.approx(diag.explained)
    assert closest is diag.steps[-1] and closest.effects == list(pair)
    assert closest.score == pytest.approx(diag.pair_gain)


def test_a_load_cell_filter_is_the_rigs_not_an_effect(tmp_path):
    """A clean damper recorded through a 2nd-order Butterworth load-cell filter at 150 Hz
    and a 12-bit converter, no chain given: the filter delays the force by
    √2/(2π·150 Hz) = 1.50 ms, which the identified model cannot follow.  The diagnosis
    takes the rig's delay (the chain candidate), finds it within 10 % of that closed form,
    names no effect, and leaves the held-out residual at the floor.  The report saves the
    estimated chain as a rig file: ``validate`` with it and the refitted model compares
    the held-out files as the diagnosis scored them."""
    import dataclasses

    from damper_emulator.acquisition import dc_group_delay, load_rig
    from damper_emulator.acquisition.rig import ForceChannel, RigParams
    from damper_emulator.diagnose.base import START_SKIP_S
    from damper_emulator.validation import validate_file

    rig = RigParams(force=ForceChannel(filter="butterworth", order=2, cutoff_hz=150.0,
                                       adc_bits=12, full_scale_n=10_000.0))
    sheet = load_config("config/sport.yaml")
    data = list(simulate_session(example_config(None, sheet), PROTOCOL, NOISE_N, seed=4,
                                 temperature=True, form=REALISTIC, rig=rig).values())
    diag = identify_and_diagnose(sheet, data, ["valve_lag", "series_compliance"])
    doc = diag.to_json()
    assert diag.family == "none" and not diag.steps, (doc["rounds"], doc["acquisition"])
    acq = doc["acquisition"]
    assert acq["source"] == "estimated"
    assert acq["force_delay_s"] == pytest.approx(math.sqrt(2) / (2 * math.pi * 150.0),
                                                 rel=0.1)
    assert 0 < acq["force_delay_std_s"] < 0.1 * acq["force_delay_s"]
    before = pooled(diag.rms_before, diag.held_out)
    after = pooled(diag.rms_after, diag.held_out)
    assert after <= max(diag.floor_n, 2.0 * NOISE_N) and after < 0.25 * before
    # the delay is the rig's: not among the damper's parameters
    assert "acquisition_delay_s" not in doc["base_parameters_after"]["values"]
    write_report(diag, tmp_path)
    saved = load_rig(tmp_path / "rig_estimated.yaml")
    assert dc_group_delay(saved.force) == pytest.approx(acq["force_delay_s"], rel=1e-9)
    model = DamperModel(load_config(tmp_path / "params_refit.yaml"))
    for d in data[2:]:
        series = validate_file(model, dataclasses.replace(d, acquisition=saved))["series"]
        k = series["time"] >= series["time"][0] + START_SKIP_S
        err = (series["force_simulated"] - series["force_measured"])[k]
        assert math.sqrt(np.mean(err ** 2)) == pytest.approx(diag.rms_after[d.name],
                                                             rel=1e-6), d.name


def test_the_fits_run_on_any_executor_in_self_contained_tasks():
    """A spawned process pool shares nothing with this process (no fork, no globals), as
    a cluster's workers would: the same diagnosis comes back."""
    sheet, data = truth_session("valve_lag")
    cfg = identify(data[0], data[1], sheet).config
    # a few evaluations per fit: the point is that both executors give the same fits
    kw = {"max_effects": 1, "nfev": FEW_NFEV}
    local = diagnose(DamperModel(cfg), data[:2], data[2:], ["valve_lag"], jobs=1, **kw)
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
        remote = diagnose(DamperModel(cfg), data[:2], data[2:], ["valve_lag"],
                          executor=pool, **kw)
    assert remote.family == local.family == "valve_dynamics"
    # the same fits (the compiled kernels of another process agree to ~1e-7, and the
    # least-squares stop then falls a step apart)
    assert remote.rms_after == pytest.approx(local.rms_after, rel=1e-4)


def blas_threads() -> list[int]:
    """The threads of each BLAS library loaded in this process."""
    from threadpoolctl import threadpool_info

    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


class Stop(Exception):
    """Raised by a stand-in to end the call under test where it was seen."""


def assert_one_blas_thread_inside(monkeypatch, module, name: str, call) -> None:
    """``call()`` reaches ``module.name`` (replaced by a stand-in that records the BLAS
    threads there, then stops the call) with :data:`FIT_BLAS_THREADS` threads in every
    BLAS library, from a caller at two, who has its two back after."""
    from threadpoolctl import threadpool_limits

    from damper_emulator.blas import FIT_BLAS_THREADS

    seen: list[list[int]] = []

    def stand_in(*args, **kwargs):
        seen.append(blas_threads())
        raise Stop

    monkeypatch.setattr(module, name, stand_in)
    with threadpool_limits(limits=2, user_api="blas"):
        before = blas_threads()
        assert before and all(n == 2 for n in before)  # numpy's and scipy's OpenBLAS
        with pytest.raises(Stop):
            call()
        assert blas_threads() == before
    assert seen == [[FIT_BLAS_THREADS] * len(before)]


def test_a_fit_task_runs_blas_on_one_thread_and_gives_the_caller_its_threads_back(
        monkeypatch):
    """Each fit task is one core's work: BLAS threads of its own would compete with the
    other workers' fits (a diagnosis 1.4x slower on 2 cores) and make its arithmetic
    depend on the machine's core count."""
    from damper_emulator.diagnose import tasks
    from damper_emulator.diagnose.tasks import FitTask, run_fit_task

    _, data = truth_session("valve_lag")
    task = FitTask(load_config(), (data[0], data[1]), (data[2],), (1.0, 1.0), {}, (), None)
    assert_one_blas_thread_inside(monkeypatch, tasks, "joint_fit", lambda: run_fit_task(task))


def test_a_diagnosis_runs_blas_on_one_thread_in_its_own_process_too(monkeypatch):
    """The fits a diagnosis runs in the caller's process (a discovered term's refits, the
    model-free stage) take one BLAS thread, as each fit task: OpenBLAS's spinning threads
    would compete with the Jacobian's threads and the pool's fits.  The caller gets its
    threads back."""
    from damper_emulator.diagnose import selection

    _, data = truth_session("valve_lag")
    assert_one_blas_thread_inside(
        monkeypatch, selection, "check_inputs",
        lambda: diagnose(DamperModel(load_config()), data[:2], data[2:]))


def test_identify_runs_blas_on_one_thread_so_its_bits_do_not_follow_the_core_count(
        monkeypatch):
    """The identified model is where a diagnosis starts, and its fits can follow the last
    bits: an identification on the caller's BLAS threads (threaded sums split by thread)
    gave a diagnosis on two cores another answer than on one.  The caller gets its threads
    back."""
    from damper_emulator.identify import pipeline

    _, data = truth_session("valve_lag")
    assert_one_blas_thread_inside(
        monkeypatch, pipeline, "aligned_tests",
        lambda: pipeline.identify(data[0], data[1], load_config()))


def test_noise_level_and_structure_ratio_follow_their_definitions():
    rng = np.random.default_rng(0)
    noise = rng.normal(0.0, 3.0, 20000)
    assert noise_level(noise) == pytest.approx(3.0, rel=0.03)
    assert structure_ratio([noise]) == pytest.approx(1.0, abs=0.03)
    t = np.linspace(0.0, 10.0, 20000)
    smooth = 4.0 * np.sin(2 * np.pi * t)  # hardly changes between samples
    # r.m.s. √(9 + 8) over the noise level 3
    assert structure_ratio([noise + smooth]) == pytest.approx(math.sqrt(17.0) / 3.0,
                                                              rel=0.03)


def test_a_report_links_its_parameters_only_where_they_move_with_it(tmp_path):
    folder = tmp_path / "a" / "report"
    assert named_from(str(folder / "p.yaml"), folder) == "[p.yaml](p.yaml)"
    assert named_from(str(tmp_path / "a" / "p.yaml"), folder) == "[p.yaml](../p.yaml)"
    far = tmp_path / "b" / "p.yaml"           # elsewhere: the path as the user gave it
    assert named_from(str(far), folder) == f"`{far}`"
    assert named_from("", folder) == ""


def test_cli_identify_then_diagnose_writes_the_contract_json_report_and_params(
        tmp_path, capsys):
    effect = "valve_lag"
    data = simulate_session(example_config(effect), PROTOCOL, noise_std_n=NOISE_N, seed=5,
                            form=REALISTIC)
    paths = write_session(data, tmp_path / "data")
    names = list(paths)
    params = tmp_path / "identified.yaml"
    # the files are raw, and the rig file says so (the diagnosis estimates no delay)
    rig = tmp_path / "rig.yaml"
    rig.write_text("rig:\n  force:\n    filter: none\n")
    assert main(["identify", "--quasi-static", str(paths[names[0]]), "--chirp",
                 str(paths[names[1]]), "--base", "config/sport.yaml", "--out",
                 str(params), "--rig", str(rig)]) == 0
    assert json.loads(params.with_suffix(".json").read_text())["acquisition"]["source"] \
        == "given"
    out_json = tmp_path / "diag.json"
    chosen = ["valve_lag", "series_compliance"]
    rc = main(["diagnose", "--params", str(params), "--quasi-static", str(paths[names[0]]),
               "--chirp", str(paths[names[1]]), "--validate",
               *(str(paths[n]) for n in names[2:]), "--json", str(out_json),
               "--report", str(tmp_path / "report"), "--jobs", "2",
               "--effects", ",".join(chosen), "--rig", str(rig)])
    assert rc == 0
    doc = json.loads(out_json.read_text())
    assert doc["family"] == "valve_dynamics" and doc["effect"] == "valve_lag"
    assert doc["significant"] is True
    assert [e["effect"] for e in doc["effects"]] == ["valve_lag"]
    assert doc["effects"][0]["held_out_gain"] == pytest.approx(doc["score"])
    assert set(doc["rms_before"]) == set(doc["rms_after"]) == set(names)
    assert {c["effect"] for c in doc["candidates"]} == set(chosen)
    assert doc["thresholds"]["floor_force_fraction"] == FLOOR_FORCE_FRACTION
    assert doc["floor_N"] > 0 and doc["refit"]["rms"].keys() == set(names)
    # the noise level of what the valve lag left is the noise the truth added (the
    # refitted model's, the first floor's, is raised by the lag's own residual)
    assert doc["noise_after_N"] == pytest.approx(NOISE_N, rel=0.15)
    assert doc["noise_N"] > doc["noise_after_N"]
    for c in doc["candidates"]:
        assert c["family"] == EXTENSION_FAMILIES[c["effect"]]
        assert isinstance(c["score"], float)
    for n in names[2:]:
        assert doc["rms_after"][n] < 0.5 * doc["rms_before"][n]
    report = tmp_path / "report"
    for n in names[2:]:
        assert (report / f"overlay_{n[:-4]}.png").stat().st_size > 10_000
    assert (report / "ranking.png").stat().st_size > 10_000
    text = (report / "report.md").read_text()
    assert "valve_lag" in text
    # the parameters beside the report folder: named relative to it, as a link that
    # resolves from the report
    assert "Identified parameters: [identified.yaml](../identified.yaml)." in text
    assert (report / "../identified.yaml").resolve() == params.resolve()
    extended = load_config(report / "params_with_effect.yaml")
    assert extended.damper.extensions.active() == ["valve_lag"]
    assert extended.damper.extensions.valve_lag.time_constant_s == pytest.approx(
        doc["parameters"]["time_constant_s"])
    # the re-identified paper's parameters are in it too
    assert extended.damper.rebound.k_port == pytest.approx(
        doc["base_parameters_after"]["values"]["rebound.k_port"])
    assert load_config(report / "params_refit.yaml").damper.extensions is None
    out = capsys.readouterr()
    assert "diagnosis: valve_dynamics" in out.out
    # progress: the refit and two effects (the chain is given: no delay estimated)
    assert "round 1 [3/3]" in out.err
    assert doc["acquisition"]["source"] == "given"
    assert doc["acquisition"]["rig"]["force"]["filter"] == "none"
    # the valve lag on the data sheet's 0.5 ms sub-step: its own integration error is
    # more than half the noise (diagnose.numerics; the chirp alone moves 6 N on halving),
    # so the effects were fitted again on half the sub-step, which the model written keeps;
    # halving that moves the force by half as much or less (second order: a quarter)
    num, h = doc["numerics"], load_config().numerics.max_substep_s
    first = num["refined_from"]
    assert first["max_substep_s"] == h and first["converged"] is False
    assert first["change_on_halving_n"] > first["noise_fraction"] * first["noise_n"]
    assert num["max_substep_s"] == h / 2 == extended.numerics.max_substep_s
    assert set(num["change_on_halving_per_file_n"]) == set(names)
    assert num["change_on_halving_n"] < first["change_on_halving_n"] / 2.0
    assert f"on {1e3 * h / 2:.3g} ms sub-steps, which the model after keeps" in text


@pytest.mark.parametrize(("extra", "message"), [
    (["--effects", "lugre_friction,warp_drive"], "unknown effect 'warp_drive'"),
    (["--quasi-static", "/nonexistent/qs.csv"], "qs.csv"),
    (["--series", "chirp.csv", "quasi_static.csv"],
     "the series order misses 'sine_1hz.csv': it must name every data file once"),
])
def test_cli_bad_input_is_one_line_and_exit_2(tmp_path, capsys, extra, message):
    data = simulate_session(load_config(), PROTOCOL, noise_std_n=NOISE_N, seed=1)
    paths = list(write_session(data, tmp_path).values())
    args = ["diagnose", "--params", "config/sport.yaml", "--quasi-static", str(paths[0]),
            "--chirp", str(paths[1]), "--validate", str(paths[2]), "--json",
            str(tmp_path / "d.json")]
    if extra[0] == "--quasi-static":
        args[args.index("--quasi-static") + 1] = extra[1]
    else:
        args += extra
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("damper-hil: error:") and message in err[0]
    assert not (tmp_path / "d.json").exists()


def test_cli_refuses_a_params_file_that_already_has_extensions(tmp_path, capsys):
    params = tmp_path / "extended.yaml"
    save_config(example_config("valve_lag"), params)
    data = simulate_session(load_config(), PROTOCOL, noise_std_n=NOISE_N, seed=1)
    paths = list(write_session(data, tmp_path).values())
    rc = main(["diagnose", "--params", str(params), "--quasi-static", str(paths[0]),
               "--chirp", str(paths[1]), "--validate", str(paths[2]), "--json",
               str(tmp_path / "d.json")])
    assert rc == 2
    assert "already holds damper.extensions (valve_lag)" in capsys.readouterr().err


def test_a_runaway_simulation_counts_as_refused_and_the_fit_ends_cleanly(monkeypatch):
    """A model that runs away (forces of 1e299 N: found with a series spring and a nearly
    closed gas volume on a slow record's long sub-step) is a refused point of the fit, like
    parameters the model rejects, not a Jacobian overflowing to inf that ends the whole
    diagnosis with a traceback."""
    from damper_emulator.diagnose.base import Record, base_parameters, make_record
    from damper_emulator.diagnose.candidates import candidates
    from damper_emulator.diagnose.joint import FAILED_COST, Space

    sheet, data = truth_session(())
    records = [make_record(d, False) for d in data[:2]]
    lag = next(c for c in candidates(sheet, data[:2]) if c.effect == "valve_lag")
    base = {p.name: p.start for p in base_parameters(sheet, data[:2])}
    simulate = Record.simulate

    def runaway_above_1ms(rec, model, fast=False):
        f = simulate(rec, model, fast)
        ext = model.cfg.damper.extensions
        return np.full_like(f, 1e299) if ext.valve_lag.time_constant_s > 1e-3 else f

    monkeypatch.setattr(Record, "simulate", runaway_above_1ms)
    space = Space(sheet, [], base, [lag], [{"time_constant_s": 2e-3}], [True], records,
                  [1e-3, 1e-3])
    s_runaway = space.encode(base, [{"time_constant_s": 2e-3}])
    s_sane = space.encode(base, [{"time_constant_s": 2e-4}])
    assert np.all(space.residuals(s_runaway) == FAILED_COST)
    sane = space.residuals(s_sane)
    assert np.all(np.isfinite(sane)) and np.max(np.abs(sane)) < FAILED_COST
    sol = space.solve(s_runaway, 5)  # must end, not raise from an inf Jacobian
    assert np.isfinite(sol.cost)


def _lag_space(sheet, data, monkeypatch, refuse):
    """A joint-fit space over the identification files: two paper's parameters and a valve
    lag free; ``refuse(τ)``: the lag's time constants whose simulation runs away."""
    from damper_emulator.diagnose.base import Record, base_parameters, make_record
    from damper_emulator.diagnose.candidates import candidates
    from damper_emulator.diagnose.joint import Space

    records = [make_record(d, False) for d in data[:2]]
    lag = next(c for c in candidates(sheet, data[:2]) if c.effect == "valve_lag")
    free = [p for p in base_parameters(sheet, data[:2])
            if p.name in ("gas_pressure_static_pa", "rebound.k_port")]
    base = {p.name: p.start for p in base_parameters(sheet, data[:2])}
    simulate = Record.simulate

    def runaway(rec, model, fast=False):
        f = simulate(rec, model, fast)
        tau = model.cfg.damper.extensions.valve_lag.time_constant_s
        return np.full_like(f, 1e299) if refuse(tau) else f

    monkeypatch.setattr(Record, "simulate", runaway)
    values = [{"time_constant_s": 2e-3}]
    space = Space(sheet, free, base, [lag], values, [True], records, [1e-2, 1e-2])
    return space, space.encode(base, values)


def test_the_jacobian_is_scipys_forward_difference_and_steps_back_where_refused(monkeypatch):
    """Where nothing is refused the fit's Jacobian is scipy's own 2-point difference with
    the same relative step; where the model refuses the forward step of a parameter, it is
    scipy's difference with that parameter's upper bound at the point (a backward step),
    not ``(FAILED_COST − r)/h`` (found on the FSAE data: a column of 10¹¹ that made every
    σ 10⁻¹⁵ of its value)."""
    from scipy.optimize._numdiff import approx_derivative

    from damper_emulator.diagnose.joint import DIFF_STEP

    sheet, data = truth_session(())
    space, s = _lag_space(sheet, data, monkeypatch, lambda tau: False)
    f0 = space.residuals(s)
    reference = approx_derivative(space.residuals, s, method="2-point", rel_step=DIFF_STEP,
                                  bounds=(0.0, 1.0), f0=f0)
    np.testing.assert_array_equal(space.jacobian(s), reference)

    space, s = _lag_space(sheet, data, monkeypatch, lambda tau: tau > 2.0000001e-3)
    f0 = space.residuals(s)
    ub = np.ones_like(s)
    ub[-1] = s[-1]  # the lag is the last parameter
    backward = approx_derivative(space.residuals, s, method="2-point", rel_step=DIFF_STEP,
                                 bounds=(0.0, ub), f0=f0)
    jac = space.jacobian(s)
    np.testing.assert_array_equal(jac, backward)
    assert np.all(np.abs(jac) < 1e6)


@pytest.mark.parametrize("threads", [1, 3])
def test_a_jacobian_simulates_each_record_only_for_its_own_inputs(monkeypatch, threads):
    """A step of the rig's delay filters the forces at hand (no simulation), one of the
    quasi-static friction ratio simulates the quasi-static record alone, any other both:
    and the Jacobian is the forward difference of a space that keeps nothing between
    evaluations (a new one for each), bit for bit whether its columns run on one thread
    or several."""
    from scipy.optimize._numdiff import approx_derivative

    from damper_emulator.diagnose import joint
    from damper_emulator.diagnose.base import (
        ACQUISITION_DELAY,
        QUASI_STATIC_FRICTION_RATIO,
        Record,
        base_parameters,
        make_record,
    )
    from damper_emulator.diagnose.joint import DIFF_STEP, Space

    monkeypatch.setattr(joint, "JACOBIAN_THREADS", threads)
    sheet, data = truth_session((), chain_given=False)
    records = [make_record(d, False) for d in data[:2]]   # quasi-static, chirp
    every = base_parameters(sheet, data[:2], delay=True)
    free = [p for p in every if p.name in ("gas_pressure_static_pa", "rebound.k_port",
                                           QUASI_STATIC_FRICTION_RATIO, ACQUISITION_DELAY)]
    assert len(free) == 4
    base = {p.name: p.start for p in every}
    base[ACQUISITION_DELAY] = 1e-3
    base[QUASI_STATIC_FRICTION_RATIO] = 0.8

    def space() -> Space:
        return Space(sheet, free, base, [], [], [], records, [1e-2, 1e-2])

    fit = space()
    s = fit.encode(base, [])
    f0 = fit.residuals(s)
    simulated: list[str] = []
    simulate = Record.simulate

    def counted(rec, model, fast=False, rig=None):
        simulated.append(rec.name)
        return simulate(rec, model, fast, rig)

    monkeypatch.setattr(Record, "simulate", counted)
    before = fit.evaluations
    jac = fit.jacobian(s)
    assert sorted(simulated) == sorted(["quasi_static.csv"] * 3 + ["chirp.csv"] * 2)
    assert fit.evaluations - before == 3   # the columns that simulated anything
    reference = approx_derivative(lambda x: space().residuals(x), s, method="2-point",
                                  rel_step=DIFF_STEP, bounds=(0.0, 1.0), f0=f0)
    np.testing.assert_array_equal(jac, reference)
    assert np.all(np.any(jac != 0.0, axis=0))  # every column has a slope: a real test


def test_sigma_is_the_covariance_of_the_resolved_parameters_and_infinite_for_the_rest(
        monkeypatch):
    """σ² (JᵀJ)⁻¹ on the parameters with a slope (an explicit inverse, a separate
    computation from the SVD of :meth:`Space.std`), AR(1)-inflated; a parameter refused
    both ways has no slope and an infinite σ."""
    import types

    sheet, data = truth_session(())
    space, s = _lag_space(sheet, data, monkeypatch,
                          lambda tau: abs(tau - 2e-3) > 1e-12)
    f0 = space.residuals(s)
    jac = space.jacobian(s)
    assert np.all(jac[:, -1] == 0.0) and np.all(np.any(jac[:, :-1] != 0.0, axis=0))
    sol = types.SimpleNamespace(x=s, fun=f0, cost=0.5 * float(f0 @ f0), jac=jac)
    rho = 0.5
    std = space.std(sol, rho)
    j = jac[:, :-1]
    s2 = float(f0 @ f0) / (f0.size - s.size) * (1 + rho) / (1 - rho)
    su = np.sqrt(np.diag(np.linalg.inv(j.T @ j)) * s2) * space.width[:-1]
    base, _ = space.decode(s)
    for k, (i, p) in enumerate(space.slots[:-1]):
        expected = base[p.name] * math.log(10.0) * su[k] if p.log else su[k]
        assert std[(i, p.name)] == pytest.approx(expected, rel=1e-8)
        assert 1e-8 < std[(i, p.name)] / base[p.name] < 1.0  # a σ, not rounding noise
    assert std[(0, "time_constant_s")] == math.inf


def test_the_effective_sample_count_is_that_of_the_mean_of_an_ar1_series():
    """``n (1 − ρ)/(1 + ρ)`` independent samples: the variance of the mean of an AR(1)
    series of n samples is σ²/n_eff (large n), checked on 400 simulated series, with ρ
    estimated by :func:`lag1` as the fit does."""
    from damper_emulator.diagnose.statistics import effective_samples, lag1

    rng = np.random.default_rng(7)
    n, rho = 4000, 0.9
    e = rng.standard_normal((400, n)) * math.sqrt(1.0 - rho ** 2)  # unit variance
    x = np.empty_like(e)
    x[:, 0] = rng.standard_normal(400)
    for k in range(1, n):
        x[:, k] = rho * x[:, k - 1] + e[:, k]
    n_eff = effective_samples(n, float(np.median([lag1(r) for r in x[:50]])))
    assert np.var(x.mean(axis=1)) * n_eff == pytest.approx(1.0, abs=0.2)
    assert effective_samples(n, 0.0) == n


def test_a_joint_fit_stops_after_a_step_that_moves_neither_measure(monkeypatch):
    """The joint fit's stop (:meth:`Space.solve` with ``min_bic_step``): a step is too
    small only when it lowers the cost by less than ``JOINT_MIN_RELATIVE_STEP`` *and* the
    effective BIC by less than one unit.  White residuals 0.05 % lower are ~30 BIC units
    on the ~67,000 samples of the identification files (go on); the same on a smooth,
    strongly autocorrelated residual are a fraction of one (stop); 5 % lower is never too
    small.  A stopped fit returns the point that step started from (the last one whose
    Jacobian it took), its cost, and the differenced Jacobian there (for σ)."""
    from damper_emulator.diagnose import joint

    sheet, data = truth_session(())
    space, s = _lag_space(sheet, data, monkeypatch, lambda tau: False)
    rng = np.random.default_rng(3)
    n = space.n
    white = rng.standard_normal(n)
    smooth = np.sin(np.linspace(0.0, 6.0 * np.pi, n)) + 0.01 * white
    monkeypatch.setattr(space, "jacobian", lambda x: "jacobian")
    space._min_bic_step = joint.JOINT_MIN_BIC_STEP

    def step(before, factor):
        space._accepted = (s, before, None)
        space._last = (s, before * factor, False)
        try:
            return space._jacobian_unless_done(s)
        except joint._Converged:
            return "stop"

    small = math.sqrt(1.0 - 0.5 * joint.JOINT_MIN_RELATIVE_STEP)
    assert step(white, small) == "jacobian"
    assert step(smooth, small) == "stop"
    assert step(smooth, 0.95) == "jacobian"
    assert step(white, 1.0) == "stop"

    monkeypatch.undo()
    space, s = _lag_space(sheet, data, monkeypatch, lambda tau: False)
    monkeypatch.setattr(joint, "JOINT_MIN_RELATIVE_STEP", 1.0)
    sol = space.solve(s, 10, min_bic_step=1e30)  # every step too small: stop at the first
    assert sol.status == -2
    np.testing.assert_array_equal(sol.x, s)  # where the first step started
    f = space.residuals(sol.x)
    assert sol.cost == pytest.approx(0.5 * float(f @ f), rel=1e-12)
    np.testing.assert_array_equal(sol.jac, space.jacobian(sol.x))
    # it stopped where trf asked for the Jacobian after an accepted trial step
    assert space.evaluations > 1 + s.size


def test_the_slow_test_gets_its_own_friction_as_a_smooth_seal_gives_it():
    """The truth's seal friction is ``F tanh(ẋ / v_f)`` (``truth.REALISTIC``): the
    quasi-static test's constant 4 mm/s sees ``F tanh(4/5)`` = 0.66 F, the chirp mostly F.
    The refit's nuisance ratio (the slow files' friction over eq 4's) must come out at that
    closed form, eq 4's friction near F, and the model it reports keep one friction."""
    from damper_emulator.diagnose.base import (
        QUASI_STATIC_FRICTION_RATIO,
        base_parameters,
        make_record,
    )
    from damper_emulator.diagnose.joint import joint_fit

    sheet, data = truth_session(())
    cfg = identify(data[0], data[1], sheet).config
    records = [make_record(d, False) for d in data[:2]]
    weights = [1.0 / (math.sqrt(r.counted) * NOISE_N) for r in records]
    start = {p.name: p.start for p in base_parameters(cfg, data[:2])}
    assert start[QUASI_STATIC_FRICTION_RATIO] == 1.0
    jf = joint_fit(cfg, records, weights, start, [], None, nfev=40)
    speed = float(np.median(np.abs(records[0].velocity)))          # the test's 4 mm/s
    expected = math.tanh(speed / REALISTIC.friction_smoothing_m_s)
    truth_friction = sheet.damper.friction_force_n
    ratio = jf.base_values[QUASI_STATIC_FRICTION_RATIO]
    assert ratio == pytest.approx(expected, abs=0.1), (ratio, expected, jf.base_values)
    assert jf.base_values["friction_force_n"] == pytest.approx(truth_friction, rel=0.2)
    model = jf.model(cfg, [])
    assert model.cfg.damper.friction_force_n == jf.base_values["friction_force_n"]
    # with LuGre in the model (it replaces eq 4's friction) there is no such ratio
    assert QUASI_STATIC_FRICTION_RATIO not in {
        p.name for p in base_parameters(cfg, data[:2], ["lugre_friction"])}


def test_the_friction_search_tries_three_levels_then_the_least_of_their_parabola():
    """``search_friction`` scores each of ``FRICTION_SEARCH_FACTORS``, then once more
    where the parabola through their costs is least: on a cost quadratic in the factor
    that is its exact minimum (closed form ``c``); where the three are not convex, half-way
    from the best to its better neighbour; a failed level (``None``) is kept as tried and
    nothing more is tried."""
    from damper_emulator.diagnose.joint import FRICTION_SEARCH_FACTORS, search_friction

    grid = list(FRICTION_SEARCH_FACTORS)
    assert len(grid) == 3 and grid[1] - grid[0] == pytest.approx(grid[2] - grid[1])
    for c in (1.6, 1.13, grid[0] + 0.01):
        calls = []

        def quadratic(f, c=c):
            calls.append(f)
            return (3.0 * (f - c) ** 2 + 0.7, f)

        out = search_friction(quadratic)
        assert calls[:3] == grid and len(calls) == 4 and len(out) == 4
        assert calls[3] == pytest.approx(c, abs=1e-12)
    # a cost |f − c| (the pre-fit's valley is V-shaped near its least): close to c
    calls = []
    search_friction(lambda f: (calls.append(f), (abs(f - 1.51), f))[1])
    assert abs(calls[3] - 1.51) < 0.02
    # a least outside the range: clipped to its end, which is not tried twice
    calls = []
    search_friction(lambda f: (calls.append(f), ((f - 3.0) ** 2, f))[1])
    assert calls == grid
    # not convex (the middle highest): half-way from the best end to the middle
    calls = []
    search_friction(lambda f: (calls.append(f), (-((f - grid[1]) ** 2) - 0.1 * f, f))[1])
    assert calls[3] == pytest.approx(0.5 * (grid[2] + grid[1]))
    # a failed level: nothing more is tried, and it is never chosen
    calls = []
    out = search_friction(lambda f: (calls.append(f),
                                     None if f == grid[2] else (f, f))[1])
    assert calls == grid and out.count(None) == 1
    # every level failing: nothing more is tried
    calls = []
    assert search_friction(lambda f: calls.append(f)) == [None] * len(grid)
    assert calls == grid


def test_identify_takes_the_friction_at_speed_as_a_multiple_of_the_quasi_static_one():
    """The smooth-seal truth's quasi-static test sees ``F tanh(ẋ/v_f)`` (0.66 F at its
    4 mm/s), the chirp F.  The paper's identification carries the quasi-static friction
    into the valve fits, whose pressure drops then hold the difference; with
    ``chirp_friction_factor`` = ``1/tanh(ẋ/v_f)`` (the closed form) the configuration's
    friction is F and both preloads move to the truth's (seeds 3–5: rebound
    within 0.2 % instead of 0.9 %, compression within 0.3 % instead of 2.7 %)."""
    from damper_emulator.diagnose.base import make_record
    from damper_emulator.identify.quasi_static import IdentificationError

    sheet, data = truth_session(())
    truth = sheet.damper
    plain = identify(data[0], data[1], sheet)
    speed = float(np.median(np.abs(make_record(data[0], False).velocity)))
    factor = 1.0 / math.tanh(speed / REALISTIC.friction_smoothing_m_s)
    fast = identify(data[0], data[1], sheet, chirp_friction_factor=factor)
    assert plain.chirp_friction_factor == 1.0
    assert fast.as_dict()["chirp_friction_factor"] == factor
    assert fast.config.damper.friction_force_n == pytest.approx(
        factor * fast.quasi_static.values[2], rel=1e-12)
    assert plain.config.damper.friction_force_n < 0.8 * truth.friction_force_n
    assert fast.config.damper.friction_force_n == pytest.approx(truth.friction_force_n,
                                                                rel=0.1)

    for side in ("rebound", "compression"):
        def preload_error(ident, side=side):
            return abs(getattr(ident.config.damper, side).preload_pa
                       / getattr(truth, side).preload_pa - 1.0)

        assert preload_error(fast) < min(0.5 * preload_error(plain), 0.01), (
            side, preload_error(fast), preload_error(plain))
    for bad in (math.nan, -1.0):
        with pytest.raises(IdentificationError, match="friction factor"):
            identify(data[0], data[1], sheet, chirp_friction_factor=bad)


def test_the_delay_taken_on_a_step_keeps_the_steps_effect(sport_cfg):
    """A step's model with the rig's delay freed (``StepFit.replaces``, when the chain
    candidate wins the round after an effect) is still that effect's step: the report
    and the answer read the family from it."""
    from damper_emulator.diagnose.candidates import Candidate, Parameter
    from damper_emulator.diagnose.outcome import StepFit

    lag = Candidate("valve_lag", (Parameter("time_constant_s", 1e-4, 0.05, 1e-3, unit="s"),),
                    lambda v: dict(v))
    step = StepFit(sport_cfg, [lag], {"effect": "valve_lag", "effects": ["valve_lag"]},
                   score=0.5, delta_bic=-100.0, significant=True)
    chain = StepFit(sport_cfg, [lag], {"effect": None, "chain": True,
                                       "effects": ["valve_lag"]})
    assert chain.candidate is None
    taken = chain.replaces(step)
    assert taken.candidate is lag and taken.candidate.family == "valve_dynamics"
    assert (taken.score, taken.delta_bic, taken.significant) == (0.5, -100.0, True)
    assert taken.out["chain"]


def test_an_optional_stop_term_the_files_do_not_determine_is_held_at_its_low_end():
    """A joint fit's step 5 (``_JointFit.without_undetermined``), from the truth's plain
    progressive stops with a hydraulic stop's orifice damping switched on beside them
    (and the end-stop candidate's own guard: no orifice from files that reach the
    stroke's ends at one speed).
    The fit files enter the stops only in the quasi-static test, at 5 mm/s, where an
    orifice's ``c_h v|v|`` is a hundredth of a newton: they do not determine it.  It is
    held at its low end (σ undetermined) and the fit repeated, and the model predicts
    the held-out sines, which go into the stops at up to 0.6 m/s, within 3× the noise;
    with the orifice left on, the same sines are far off."""
    from scipy.optimize import OptimizeResult

    from damper_emulator.diagnose import joint
    from damper_emulator.diagnose.base import base_parameters, make_record
    from damper_emulator.diagnose.candidates import STOP_REFERENCE_FRACTION, candidates

    sheet, data = truth_session("end_stops")
    truth = EXAMPLE_EFFECTS["end_stops"]["params"]
    cfg = identify(data[0], data[1], sheet).config
    records = [make_record(d, False) for d in data[:2]]
    held_out = [make_record(d, True) for d in data[2:]]
    weights = [1.0 / (math.sqrt(r.counted) * NOISE_N) for r in records]
    # the fit files reach the stroke's ends in the quasi-static test alone, at one speed:
    # the candidate has no orifice to fit there (ORIFICE_SPEED_SPAN) ...
    (one_speed,) = candidates(cfg, data[:2], ["end_stops"])
    assert one_speed.held["hydraulic_damping_n_s2_m2"] == 1.0 and not one_speed.form_starts
    assert "at one speed" in one_speed.note  # the report says why
    # ... and where its law is not theirs to tell: past the stops at speed, which the
    # held-out sines reach (up to 0.6 m/s) and the fit files never do
    stops_at = {"rebound_position_m": truth["rebound_position_m"],
                "compression_position_m": truth["compression_position_m"]}
    assert one_speed.undetermined is not None and "one speed" in one_speed.limit
    for d in data[:2]:
        assert not one_speed.undetermined(d, stops_at).any(), d.name
    for d in data[2:]:
        region = one_speed.undetermined(d, stops_at)
        x, v = d.displacement[region], np.gradient(d.displacement, d.time)[region]
        assert ((x > truth["rebound_position_m"])
                | (x < truth["compression_position_m"])).all()
        assert (np.abs(v) > 0.01).all()     # 3 × the quasi-static test's 4-5 mm/s
        if np.abs(d.displacement).max() > truth["rebound_position_m"] + 0.005:
            assert region.sum() > 50, d.name           # a sine into the stops
    # ... built with a held-out sine too (it enters the stops at every speed up to its
    # top; the same stroke and top speed), it has one, which step 5 must hold here
    (stops,) = candidates(cfg, [*data[:2], data[3]], ["end_stops"])
    assert "hydraulic_damping_n_s2_m2" in {p.name for p in stops.parameters}
    start = {p.name: p.start for p in stops.parameters}
    d_ref = STOP_REFERENCE_FRACTION * (max(d.displacement.max() for d in data[:2])
                                       - min(d.displacement.min() for d in data[:2]))
    on = {**start, "rebound_position_m": truth["rebound_position_m"],
          "compression_position_m": truth["compression_position_m"],
          "reference_force_n": truth["stiffness_n_m2"] * d_ref ** 2,
          "progressive_exponent": 2.0, "linear_stiffness_n_m": 1.0, "hysteresis": 0.0,
          "damping_n_s_m2": 1.0, "compression_scale": 1.0,
          "hydraulic_damping_n_s2_m2": 3e3}
    fit = joint._JointFit(cfg, records, weights, 1, joint.JOINT_NFEV, None, (), [stops])
    # the paper's parameters fitted jointly with the truth's stops (the orifice held
    # off), then the orifice switched on there
    ref, ref_sol = fit.fit_from({p.name: p.start for p in base_parameters(cfg, data[:2])},
                                [on], [stops.holding({"hydraulic_damping_n_s2_m2"})])
    base, (values,) = ref.decode(ref_sol.x)
    on = {**values, "hydraulic_damping_n_s2_m2": 3e3}
    space = joint.Space(cfg, base_parameters(cfg, data[:2]), base, [stops], [on], [True],
                        records, weights)
    s = space.encode(base, [on])
    f = space.residuals(s)
    at_on = OptimizeResult(x=s, fun=f, cost=0.5 * float(f @ f), jac=space.jacobian(s))

    def held_out_rms(sp, x):
        model = sp.model(x)
        return math.sqrt(np.mean(np.concatenate([r.residual(model) for r in held_out]) ** 2))

    kept, sol, std, n = fit.without_undetermined(space, at_on)
    held = set(kept.cands[0].held)
    assert {"hydraulic_damping_n_s2_m2", "hydraulic_engagement_m"} <= held
    by_name = {p.name: p for p in stops.parameters}
    assert all(by_name[name].optional or by_name[name].part_of for name in held), held
    assert not held & {name for _, name in std}  # no longer free: no σ of their own
    assert n > 0
    _, values = kept.decode(sol.x)
    assert (values[0]["hydraulic_damping_n_s2_m2"]
            == by_name["hydraulic_damping_n_s2_m2"].lo)
    assert held_out_rms(kept, sol.x) <= 3.0 * NOISE_N
    # accepted with these values, the stops keep the orifice held in later fits
    assert held <= set(stops.settled(values[0]).held)
    assert held_out_rms(space, s) > 10.0 * NOISE_N
