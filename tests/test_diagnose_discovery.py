"""``diagnose`` on effects outside the library of extensions, as a user runs it
(``identify`` on the truth data's quasi-static and chirp files with the damper's data sheet,
then ``diagnose`` with the sines held out): a mass alone is discovered as a term and read as
``inertia``; beside a library effect (a LuGre friction, a cavity) the term discovered on
what the effect left is reported with it, a mass as a mass and a damping zone where the
truth has it.

The truth differs in model form from the emulator's model (``truth.REALISTIC``), and each
test tries the few candidates that act most as the outside effect does (the benchmark,
``benchmarks/diagnose_bench.py``, runs all of them).  Apart from ``test_diagnose.py`` so
that the test processes share the slow diagnoses between them."""

from __future__ import annotations

import numpy as np
import pytest
from diagnose_support import (
    LONGER_PROTOCOL,
    NOISE_N,
    PARAMETER_TOLERANCE,
    identify_and_diagnose,
    pooled,
    truth_session,
)

from damper_emulator.diagnose.outcome import (
    MIN_EXPLAINED,
    MIN_SCORE,
    STRUCTURE_RATIO,
    explained_fraction,
)
from damper_emulator.diagnose.report import markdown, write_report
from damper_emulator.diagnose.truth import EXAMPLE_EFFECTS
from damper_emulator.params import load_config

pytestmark = pytest.mark.slow

def test_an_effect_outside_the_library_is_discovered_and_read_as_inertia(tmp_path):
    """A 6 kg mass between load cell and damper (``F + m ẍ``): no extension has an
    inertial force, and the library leaves structure (the answer was ``other``).  The
    discovery regresses what is left on its dictionary, reads the mass from the
    acceleration, names the family from that variable, and brings the held-out residual
    within twice the noise; the rig's delay is estimated (none here) and is not what
    took the inertia."""
    mass_kg = 6.0

    def inertia(t, x, v):
        return mass_kg * np.gradient(v, t)

    sheet, data = truth_session(None, extra_force=inertia, chain_given=False,
                                protocol=LONGER_PROTOCOL)
    # the candidate that acts on the force's phase most as a mass does, and takes part of
    # it first (the benchmark runs all nine)
    diag = identify_and_diagnose(sheet, data, ["valve_lag"])
    assert diag.structure_before > STRUCTURE_RATIO  # there is something to find
    doc = diag.to_json()
    found = doc["discovered"]
    assert diag.family == "inertia" and diag.effect == "discovered" and diag.significant, (
        doc["rounds"], found)
    assert not diag.steps
    terms = {c["term"]: c for c in found["coefficients"]}
    assert terms["ẍ"]["value"] == pytest.approx(mass_kg, rel=0.1)
    # the term is in the model, as an extension the compiled step runs (the emulator's,
    # the ride's, replay's): run so, it leaves the held-out residual the discovery scored
    ext = diag.model_after().cfg.damper.extensions
    assert ext.active() == ["discovered_term"]
    assert ext.discovered_term.acceleration_kg == pytest.approx(terms["ẍ"]["value"])
    for rec in (r for r in diag.records if r.held_out):
        res = rec.residual(diag.model_after(), rig=diag.rig_after())
        assert np.sqrt(np.mean(res ** 2)) == pytest.approx(
            found["rms_held_out_after"][rec.name], rel=1e-3)
    assert terms["ẍ"]["unit"] == "kg" and found["family_hint"] == "inertia"
    assert max(found["rms_held_out_after"].values()) < 2 * NOISE_N
    assert found["held_out_gain"] >= MIN_SCORE and found["significant"]
    # one mass in every test: fitted on each file alone, the model held
    assert found["stable"] and found["trust"].startswith("ready"), found["trust"]
    masses = [parts[0]["value"] for parts in found["per_file"].values()]
    assert len(masses) == len(diag.records)
    # the rig's delay competed, and was not taken: a mass leads, a filter lags
    assert doc["acquisition"]["source"] == "none"
    # the report shows the term against its variable
    text = markdown(diag)
    assert "## Term discovery" in text and "kg · ẍ" in text
    assert "a term discovered in it is significant" in text
    assert "Nothing to add" not in text
    # the report's params file holds the term, and every command loads it back
    files = write_report(diag, tmp_path)
    assert tmp_path / "params_with_effect.yaml" in files
    loaded = load_config(tmp_path / "params_with_effect.yaml")
    assert loaded.damper.extensions.discovered_term == ext.discovered_term
    assert (tmp_path / "discovered.png").stat().st_size > 0


def test_a_library_effect_and_the_term_discovered_beside_it_are_both_reported():
    """A LuGre friction (the library's) and a 6 kg mass between load cell and damper, the
    library's inertia left out of the candidates.  The friction, after a valve lag that
    takes part of the mass's phase lead, explains under half of the structure: too little
    to be the answer alone (step 7).  The term discovered on what they left is the mass;
    fitted with them, the valve lag gains nothing beside it and goes, and the friction
    and the mass are reported together, the model after holding both."""
    mass_kg = 6.0

    def inertia(t, x, v):
        return mass_kg * np.gradient(v, t)

    sheet, data = truth_session(("lugre_friction",), extra_force=inertia)
    diag = identify_and_diagnose(sheet, data, ["lugre_friction", "valve_lag"])
    held = [r for r in diag.records if r.held_out]
    # the library's effects alone (their own fit, without the term) explained too little
    assert explained_fraction(diag.refit.residuals(held),
                              diag.steps[-1].residuals(held)) < MIN_EXPLAINED
    doc = diag.to_json()
    assert diag.family == "friction" and diag.effect == "lugre_friction", doc["effects"]
    assert [e["effect"] for e in doc["effects"]] == ["lugre_friction", "discovered_term"]
    assert diag.explained >= MIN_EXPLAINED and doc["closest"] is None
    term = doc["discovered"]
    assert term["family_hint"] == "inertia" and term["significant"]
    (part,) = term["coefficients"]
    assert part["term"] == "ẍ" and part["value"] == pytest.approx(mass_kg, rel=0.1)
    truth = EXAMPLE_EFFECTS["lugre_friction"]["params"]
    friction = doc["effects"][0]["parameters"]
    assert friction["coulomb_n"] == pytest.approx(truth["coulomb_n"], rel=PARAMETER_TOLERANCE)
    # the JSON's effect is the model after's: the one refitted with the term
    ext = diag.model_after().cfg.damper.extensions
    assert set(ext.active()) == {"lugre_friction", "discovered_term"}
    assert ext.lugre_friction.coulomb_n == pytest.approx(friction["coulomb_n"])
    assert pooled(diag.rms_after, diag.held_out) < 2.0 * NOISE_N
    assert pooled(diag.rms_after, diag.held_out) < 0.1 * pooled(diag.rms_before,
                                                                 diag.held_out)


def test_a_zone_beside_a_cavity_is_fitted_where_the_truth_has_it():
    """A cavity (the library's) and a damping zone outside the library: 600 N·s/m over a
    Gaussian at 8 mm, 6 mm wide.  Identified with the zone in the data, the compression
    valve takes the zone's damping, and the cavity's fit bends the paper's parameters
    further.  The term discovered beside the cavity is the zone; fitted with the model
    (its centre and width free, from the paper's model identified again without the
    term's force) it comes back where the truth has it, and the held-out residual to the
    noise.  On the longer chirp: on the 8 s one the joint fit ends where the kernels'
    last bits take it (those of a process that compiled the kernels and those of one
    that loaded them give two answers there)."""
    gain, centre, width = 600.0, 0.008, 0.006

    def zone(t, x, v):
        return gain * np.exp(-0.5 * ((x - centre) / width) ** 2) * v

    sheet, data = truth_session(("cavitation",), extra_force=zone, protocol=LONGER_PROTOCOL)
    diag = identify_and_diagnose(sheet, data, ["cavitation", "air_entrainment"])
    doc = diag.to_json()
    assert [s.candidate.effect for s in diag.steps] == ["cavitation"], doc["rounds"]
    term = doc["discovered"]
    assert term["family_hint"] == "position_dependent" and term["significant"], term
    fitted = doc["effects"][-1]["parameters"]
    assert fitted["profile_n_s_m"] == pytest.approx(gain, rel=0.05)
    assert fitted["profile_center_m"] == pytest.approx(centre, abs=0.03 * width)
    assert fitted["profile_width_m"] == pytest.approx(width, rel=0.05)
    assert pooled(diag.rms_after, diag.held_out) <= max(diag.floor_n, 2.0 * NOISE_N)
