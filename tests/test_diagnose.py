"""``diagnose``: data made by the truth simulation with one effect (own parameters, noise
added, nothing saying which) must come back as that effect's family with the held-out
r.m.s. at least halved and the truth's parameters recovered; data without an effect as
``none``; data with an effect outside the library as ``other`` or the closest family, with
an improvement that holds when checked by ``validate``."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from damper_emulator.cli import main
from damper_emulator.diagnose.selection import (MIN_SCORE, STRUCTURE_RATIO, diagnose,
                                                noise_level, structure_ratio)
from damper_emulator.diagnose.truth import (EXAMPLE_EFFECTS, Protocol, example_config,
                                            simulate_session, with_extension, write_session)
from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import EXTENSION_FAMILIES, load_config
from damper_emulator.validation import validate_file

#: a shorter chirp and one quasi-static cycle keep the suite quick; the rest as the paper
#: (the full protocol: benchmarks/diagnose_bench.py)
PROTOCOL = Protocol(chirp_duration_s=12.0, qs_cycles=1)
NOISE_N = 2.0
#: relative tolerance on each recovered parameter (the truth is known exactly)
PARAMETER_TOLERANCE = {"lugre_friction": 0.25, "end_stops": 0.1, "bypass_groove": 0.2}
DEFAULT_TOLERANCE = 0.1


def _base_config(effect):
    changes = EXAMPLE_EFFECTS[effect].get("base") if effect else None
    return with_extension(load_config(), None, None, changes)


def _run(truth_cfg, base_cfg, *, seed=3, temperature=False, extra_force=None):
    data = list(simulate_session(truth_cfg, PROTOCOL, noise_std_n=NOISE_N, seed=seed,
                                 temperature=temperature, extra_force=extra_force).values())
    return diagnose(DamperModel(base_cfg), data[:2], data[2:], jobs=2), data


def _pooled(rms: dict[str, float], names) -> float:
    return math.sqrt(sum(rms[n] ** 2 for n in names) / len(names))


@pytest.mark.parametrize("effect", list(EXAMPLE_EFFECTS))
def test_each_family_is_found_with_its_parameters_and_halves_the_held_out_error(effect):
    truth = example_config(effect)
    diag, _ = _run(truth, _base_config(effect),
                   temperature=effect == "viscosity_temperature")
    assert diag.family == EXTENSION_FAMILIES[effect], (
        f"{effect}: diagnosed {diag.family}; ranking "
        + ", ".join(f"{c.candidate.effect} {c.score:.3f}/{c.delta_bic:.0f}"
                    for c in diag.ranking))
    assert diag.effect == effect and diag.significant
    before = _pooled(diag.rms_before, diag.held_out)
    after = _pooled(diag.rms_after, diag.held_out)
    assert after <= 0.5 * before, (effect, before, after)
    # the truth's own parameters come back (they were never given to diagnose)
    truth_params = EXAMPLE_EFFECTS[effect]["params"]
    tol = PARAMETER_TOLERANCE.get(effect, DEFAULT_TOLERANCE)
    for name, value in diag.chosen.extension.items():
        if name in truth_params:
            assert value == pytest.approx(truth_params[name], rel=tol, abs=1e-4), (
                effect, name, value, truth_params[name])
    # nothing but noise is left on the held-out files
    assert diag.structure_after < STRUCTURE_RATIO


def test_without_an_extra_effect_the_answer_is_none():
    base = _base_config(None)
    diag, _ = _run(base, base)
    assert diag.family == "none" and diag.effect is None and not diag.significant
    assert diag.rms_after == diag.rms_before
    # the residual is the noise that was added
    for name in diag.held_out:
        assert diag.rms_before[name] == pytest.approx(NOISE_N, rel=0.1)
    assert all(c.score < MIN_SCORE for c in diag.ranking)


def test_an_effect_outside_the_library_gives_other_and_an_honest_closest_family():
    """A 6 kg mass between load cell and damper (``F + m ẍ``): no extension has an
    inertial force.  The answer is ``other``; the closest candidate (if any is significant)
    is named with the improvement it really gives, which ``validate`` confirms."""
    mass_kg = 6.0

    def inertia(t, x, v):
        return mass_kg * np.gradient(v, t)

    base = _base_config(None)
    diag, data = _run(base, base, extra_force=inertia)
    assert diag.structure_before > STRUCTURE_RATIO  # there is something to find
    assert diag.family == "other" and diag.effect is None and not diag.significant
    assert diag.rms_after == diag.rms_before  # nothing added, nothing claimed
    if diag.closest is not None:
        c = diag.closest
        assert diag.explained < 0.5 and c.score < 0.5
        from damper_emulator.diagnose.selection import with_candidate

        model = with_candidate(diag.base_model, c.candidate, c.values)
        for d in data:
            if d.name in diag.held_out:  # validate counts the 50 ms start-up too
                assert validate_file(model, d)["rms_N"] == pytest.approx(
                    c.rms_held_out[d.name], rel=0.25)
    doc = diag.to_json()
    assert doc["family"] == "other" and doc["significant"] is False


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


def test_cli_writes_the_contract_json_report_and_an_extended_params_file(tmp_path, capsys):
    effect = "valve_lag"
    data = simulate_session(example_config(effect), PROTOCOL, noise_std_n=NOISE_N, seed=5)
    paths = write_session(data, tmp_path / "data")
    params = tmp_path / "identified.yaml"
    from damper_emulator.params import save_config

    save_config(_base_config(effect), params)
    out_json = tmp_path / "diag.json"
    names = list(paths)
    rc = main(["diagnose", "--params", str(params), "--quasi-static", str(paths[names[0]]),
               "--chirp", str(paths[names[1]]), "--validate",
               *(str(paths[n]) for n in names[2:]), "--json", str(out_json),
               "--report", str(tmp_path / "report"), "--jobs", "2"])
    assert rc == 0
    doc = json.loads(out_json.read_text())
    assert doc["family"] == "valve_dynamics" and doc["effect"] == "valve_lag"
    assert doc["significant"] is True
    assert set(doc["rms_before"]) == set(doc["rms_after"]) == set(names)
    assert {c["effect"] for c in doc["candidates"]} == set(EXTENSION_FAMILIES)
    for c in doc["candidates"]:
        assert c["family"] == EXTENSION_FAMILIES[c["effect"]]
        assert isinstance(c["score"], float)
    for n in names[2:]:
        assert doc["rms_after"][n] < 0.5 * doc["rms_before"][n]
    report = tmp_path / "report"
    for n in names[2:]:
        assert (report / f"overlay_{n[:-4]}.png").stat().st_size > 10_000
    assert (report / "ranking.png").stat().st_size > 10_000
    assert "valve_lag" in (report / "report.md").read_text()
    extended = load_config(report / "params_with_effect.yaml")
    assert extended.damper.extensions.active() == ["valve_lag"]
    assert extended.damper.extensions.valve_lag.time_constant_s == pytest.approx(
        doc["parameters"]["time_constant_s"])
    out = capsys.readouterr()
    assert "diagnosis: valve_dynamics" in out.out
    assert "[9/9]" in out.err  # progress


@pytest.mark.parametrize("extra, message", [
    (["--effects", "lugre_friction,warp_drive"], "unknown effect 'warp_drive'"),
    (["--quasi-static", "/nonexistent/qs.csv"], "qs.csv"),
])
def test_cli_bad_input_is_one_line_and_exit_2(tmp_path, capsys, extra, message):
    data = simulate_session(_base_config(None), PROTOCOL, noise_std_n=NOISE_N, seed=1)
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
    from damper_emulator.params import save_config

    params = tmp_path / "extended.yaml"
    save_config(example_config("valve_lag"), params)
    data = simulate_session(_base_config(None), PROTOCOL, noise_std_n=NOISE_N, seed=1)
    paths = list(write_session(data, tmp_path).values())
    rc = main(["diagnose", "--params", str(params), "--quasi-static", str(paths[0]),
               "--chirp", str(paths[1]), "--validate", str(paths[2]), "--json",
               str(tmp_path / "d.json")])
    assert rc == 2
    assert "already holds damper.extensions (valve_lag)" in capsys.readouterr().err
