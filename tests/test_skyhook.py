"""The continuous semi-active skyhook law (ride_sim/skyhook.py) against hand-derived cases,
and its parameters (config/skyhook.yaml)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from damper_emulator.model.compressible import DamperModel
from damper_emulator.schema import ParameterError, read_yaml
from ride_sim.skyhook import (
    DEFAULT_SKYHOOK_FILE,
    SkyhookParams,
    SkyhookRates,
    check_rates,
    equivalent_rates,
    load_skyhook,
    resolve_rates,
    skyhook_command,
    skyhook_from_mapping,
)

#: hand-made rates: rebound soft 1000 / firm 5000, compression soft 800 / firm 2000 N s/m
RATES = SkyhookRates(1000.0, 5000.0, 800.0, 2000.0)
C_SKY = 4000.0
DEADBAND = 0.01


def law(vb, vd):
    return skyhook_command(vb, vd, C_SKY, RATES, DEADBAND)


@pytest.mark.parametrize(("vb", "vd", "expected"), [
    # rebound, same sign: required 4000·0.2/0.4 = 2000 → (2000 − 1000)/4000
    (0.2, 0.4, 0.25),
    # compression, same sign: 4000·0.1/0.25 = 1600 → (1600 − 800)/1200
    (-0.1, -0.25, 2.0 / 3.0),
    # compression: 2000 = the firm rate exactly → 1
    (-0.2, -0.4, 1.0),
    # clipped above: 4000·1/0.1 = 40000 → 1
    (1.0, 0.1, 1.0),
    # clipped below: 4000·0.01/1 = 40 < soft → 0
    (0.01, 1.0, 0.0),
    (-0.1, -0.5, 0.0),                   # 800 = the soft compression rate → 0
    # opposite signs: the force cannot be produced → softest
    (0.2, -0.4, 0.0),
    (-0.2, 0.4, 0.0),
    # zero crossings: v_d = 0 or v_b = 0 → softest
    (0.3, 0.0, 0.0),
    (0.0, 0.3, 0.0),
    (0.0, 0.0, 0.0),
    # deadband: |v_d| < 0.01 counts as 0.01: 4000·0.01/0.01 = 4000 → 0.75 (not 1)
    (0.01, 0.001, 0.75),
    (-0.01, -1e-9, 1.0),                  # 4000 at the deadband > firm compression 2000
    (0.001, 0.002, 0.0),                  # 4000·0.001/0.01 = 400 < soft
])
def test_hand_derived_cases(vb, vd, expected):
    got = law(vb, vd)
    assert isinstance(got, float)
    assert got == pytest.approx(expected, abs=1e-12)


def test_sign_of_the_damper_velocity_picks_the_direction_and_the_crossing_jumps():
    """Across v_d = 0 with the body rising: extension (same sign) asks for the rate at the
    deadband, compression (opposite sign) for the softest setting."""
    assert law(0.01, 1e-12) == pytest.approx(0.75)
    assert law(0.01, -1e-12) == 0.0
    # continuous at the deadband's edge
    assert law(0.005, 0.01) == pytest.approx(law(0.005, 0.01 - 1e-12), abs=1e-9)
    # the same |F*/v_d| maps through the direction's own rates
    assert law(0.3, 0.6) == pytest.approx((2000.0 - 1000.0) / 4000.0)
    assert law(-0.3, -0.6) == pytest.approx((2000.0 - 800.0) / 1200.0)


def test_arrays_give_the_scalar_results():
    rng = np.random.default_rng(1)
    vb = rng.normal(0, 0.2, 200)
    vd = rng.normal(0, 0.3, 200)
    vd[:5] = 0.0
    vd[5:10] = 1e-4
    got = law(vb, vd)
    assert got.shape == (200,)
    assert np.array_equal(got, [law(a, b) for a, b in zip(vb, vd)])
    assert np.all((got >= 0) & (got <= 1))
    assert np.all(got[vb * vd <= 0] == 0.0)


def test_default_file():
    p = load_skyhook()
    assert p == SkyhookParams(c_sky_ns_m=5000.0)        # the file states the defaults
    assert DEFAULT_SKYHOOK_FILE.name == "skyhook.yaml"


def test_rates_from_the_model_and_the_documented_values(sport_model):
    """From the sport damper at 0.2 m/s: firm > soft in both directions, and the values the
    config file documents for rates_from: config (within 0.1 %)."""
    p = load_skyhook()
    r = resolve_rates(p, sport_model)
    assert r == equivalent_rates(sport_model, 0.2)
    doc = SkyhookParams(c_sky_ns_m=1.0)
    for got, documented in zip(r, (doc.c_soft_rebound_ns_m, doc.c_firm_rebound_ns_m,
                                   doc.c_soft_compression_ns_m, doc.c_firm_compression_ns_m)):
        assert got == pytest.approx(documented, rel=1e-3)
    fs = sport_model.cfg.damper.static_force_n
    from damper_emulator.model.compressible import quasi_steady_force
    assert r.firm_rebound == pytest.approx((quasi_steady_force(sport_model, 0.2) - fs) / 0.2,
                                           rel=1e-9)


def test_rates_from_config(sport_model):
    p = SkyhookParams(c_sky_ns_m=1.0, rates_from="config", c_soft_rebound_ns_m=10.0,
                      c_firm_rebound_ns_m=20.0, c_soft_compression_ns_m=5.0,
                      c_firm_compression_ns_m=6.0)
    assert resolve_rates(p, sport_model) == SkyhookRates(10.0, 20.0, 5.0, 6.0)


def test_a_damper_without_bypass_cannot_be_controlled(sport_cfg):
    plain = DamperModel(sport_cfg.replace_damper(adaptive=None))
    with pytest.raises(ParameterError, match="must exceed") as err:
        resolve_rates(SkyhookParams(c_sky_ns_m=1.0), plain)
    assert "\n" not in str(err.value)
    with pytest.raises(ParameterError, match="soft_rebound"):
        check_rates(SkyhookRates(math.nan, 1.0, 1.0, 2.0))


def _doc():
    return read_yaml(DEFAULT_SKYHOOK_FILE)


@pytest.mark.parametrize(("key", "value", "words"), [
    ("c_sky_ns_m", -5.0, "skyhook.c_sky_ns_m = -5 must be positive"),
    ("rate_hz", 0.0, r"skyhook.rate_hz = 0 must lie in"),
    ("deadband_m_s", 0.0, "skyhook.deadband_m_s = 0 must be positive"),
    ("rates_from", "table", "skyhook.rates_from = 'table' must be one of model, config"),
    ("reference_velocity_m_s", "fast", "skyhook.reference_velocity_m_s must be a number"),
])
def test_bad_values_are_one_line_errors(tmp_path, key, value, words):
    doc = _doc()
    doc["/**"]["ros__parameters"]["skyhook"][key] = value
    with pytest.raises(ParameterError, match=words) as err:
        skyhook_from_mapping(doc, "bad.yaml")
    assert "\n" not in str(err.value) and str(err.value).startswith("bad.yaml: ")


def test_file_errors(tmp_path):
    text = DEFAULT_SKYHOOK_FILE.read_text()
    path = tmp_path / "s.yaml"
    for old, new, words in (
            ("c_sky_ns_m: 5.0e+3", "c_sky: 5.0e+3", "unknown parameter skyhook.c_sky"),
            ("rates_from: model", "rates_from: config\n      c_firm_x: 1.0",
             "unknown parameter skyhook.c_firm_x"),
            ("rates_from: model ", "rates_from: config ", None),
            ("c_firm_compression_ns_m: 4360.0", "c_firm_compression_ns_m: 1000.0",
             None)):
        assert old in text
        path.write_text(text.replace(old, new))
        if words:
            with pytest.raises(ParameterError, match=words) as err:
                load_skyhook(path)
            assert str(path) in str(err.value) and "\n" not in str(err.value)
        else:
            load_skyhook(path)            # rates from config, or an unused config rate
    # firm below soft with rates_from: config: refused at load, naming the file
    path.write_text(text.replace("rates_from: model ", "rates_from: config ")
                    .replace("c_firm_compression_ns_m: 4360.0",
                             "c_firm_compression_ns_m: 1000.0"))
    with pytest.raises(ParameterError, match="firm compression rate") as err:
        load_skyhook(path)
    assert str(path) in str(err.value)
    path.write_text(text.replace("c_sky_ns_m: 5.0e+3", ""))
    with pytest.raises(ParameterError, match=r"missing parameter skyhook\.c_sky_ns_m"):
        load_skyhook(path)
    path.write_text("other: {}\n")
    with pytest.raises(ParameterError, match="no 'skyhook' parameters"):
        load_skyhook(path)
