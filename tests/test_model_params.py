"""Parameter files: loading, the paper's values, validation with one-line errors."""

import math

import pytest
import yaml

from damper_emulator.params import (
    DEFAULT_PARAMS_FILE,
    config_from_mapping,
    load_config,
    save_config,
)
from damper_emulator.schema import ParameterError, read_yaml


def test_sport_file_holds_the_papers_parameters(sport_cfg):
    d = sport_cfg.damper
    assert (d.pressure_tube_length_m, d.x0_m) == (0.453, 0.1355)
    assert (d.rod_diameter_m, d.piston_diameter_m) == (13e-3, 36e-3)
    assert (d.gas_gamma, d.oil_kinematic_viscosity_m2_s, d.oil_compressibility_per_pa) == (
        1.4, 21e-6, 1.5e-9)
    assert (d.friction_force_n, d.gas_volume_static_m3, d.gas_pressure_static_pa) == (
        43.7, 1.2299e-4, 2.9995e6)
    assert tuple(d.rebound) == (7.63e14, 1.20e11, 6.50e12, 2.74e6, 1.5)
    assert tuple(d.compression) == (6.54e14, 2.02e12, 1.56e12, 6.82e5, 1.7)
    assert d.annulus_area_m2 == pytest.approx(math.pi / 4 * (0.036 ** 2 - 0.013 ** 2))
    assert d.static_force_n == pytest.approx(-math.pi / 4 * 0.013 ** 2 * 2.9995e6)


def test_exponent_floats_without_dot_read_as_numbers(tmp_path):
    # ROS 2 reads 7.63e14 as a float; PyYAML's YAML 1.1 rules would make it a string.
    p = tmp_path / "p.yaml"
    p.write_text("a: 7.63e14\nb: 1e-3\nc: 2.5\nd: 3\ne: name\n")
    assert read_yaml(p) == {"a": 7.63e14, "b": 1e-3, "c": 2.5, "d": 3, "e": "name"}


def _sport_doc():
    return read_yaml(DEFAULT_PARAMS_FILE)


def _damper(doc):
    return doc["/**"]["ros__parameters"]["damper"]


def _error_for(doc):
    with pytest.raises(ParameterError) as info:
        config_from_mapping(doc, "bad.yaml")
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith("bad.yaml: ")
    return msg


@pytest.mark.parametrize(("edit", "key", "words"), [
    (lambda d: d.update(rod_diameter_m=0.04), "damper.rod_diameter_m", "smaller than"),
    (lambda d: d.update(x0_m=0.5), "damper.x0_m", "smaller than"),
    (lambda d: d.update(gas_volume_static_m3=-1e-4), "damper.gas_volume_static_m3", "positive"),
    (lambda d: d.update(pressure_tube_length_m=0.0), "damper.pressure_tube_length_m", "positive"),
    (lambda d: d.update(friction_force_n=-1.0), "damper.friction_force_n", "negative"),
    (lambda d: d.update(gas_gamma=2.5), "damper.gas_gamma", "must lie in"),
    (lambda d: d.update(oil_compressibility_per_pa=float("nan")),
     "damper.oil_compressibility_per_pa", "finite"),
    (lambda d: d["rebound"].update(preload_pa=0), "damper.rebound.preload_pa", "positive"),
    (lambda d: d["compression"].update(k_leak="lots"), "damper.compression.k_leak", "number"),
    (lambda d: d.pop("gas_pressure_static_pa"), "damper.gas_pressure_static_pa", "missing"),
    (lambda d: d.update(piston_diametre_m=0.03), "damper.piston_diametre_m", "unknown"),
])
def test_invalid_values_are_refused_naming_key_and_rule(edit, key, words):
    doc = _sport_doc()
    edit(_damper(doc))
    msg = _error_for(doc)
    assert key in msg and words in msg


def test_non_invertible_valve_is_refused():
    # A port restriction far above the leak makes the linear extension below blow-off
    # (eq 29) negative at small flow: Δp(Q) is then not monotonic and cannot be inverted.
    doc = _sport_doc()
    _damper(doc)["rebound"].update(k_port=1e16, k_leak=1e12)
    msg = _error_for(doc)
    assert "damper.rebound valve" in msg and "not strictly increasing" in msg


def test_numerics_rules():
    doc = _sport_doc()
    doc["/**"]["ros__parameters"]["numerics"]["valve_form"] = "taylor"
    assert "numerics.valve_form" in _error_for(doc)


def test_bare_mapping_and_named_node_forms_are_accepted(sport_cfg):
    body = _sport_doc()["/**"]["ros__parameters"]
    assert config_from_mapping(body).damper == sport_cfg.damper
    assert config_from_mapping({"damper_emulator": {"ros__parameters": body}}).damper == \
        sport_cfg.damper


def test_unreadable_and_malformed_files(tmp_path):
    with pytest.raises(ParameterError, match="cannot read"):
        load_config(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("damper: [1, 2\n")
    with pytest.raises(ParameterError, match="invalid YAML"):
        load_config(bad)
    bad.write_text("other: {}\n")
    with pytest.raises(ParameterError, match="no 'damper' parameters"):
        load_config(bad)


def test_save_and_load_round_trip(tmp_path, sport_cfg):
    path = tmp_path / "out.yaml"
    save_config(sport_cfg, path)
    again = load_config(path)
    assert again.damper == sport_cfg.damper and again.numerics == sport_cfg.numerics
    # what is written is a ROS 2 params file that a plain YAML 1.1 reader also parses
    doc = yaml.safe_load(path.read_text())
    assert isinstance(doc["/**"]["ros__parameters"]["damper"]["rebound"]["k_leak"], float)


@pytest.mark.parametrize("value", [1.7672139758393378e-06, 1e-20, 2.5e20, 0.1 + 0.2,
                                   5e-324, 1.7976931348623157e308, 3.0e-7])
def test_every_float_reads_back_to_the_same_double(tmp_path, sport_cfg, value):
    """A fitted value keeps all its digits through a params file (a diagnosed model
    written out is the model the report scored), and reads as a float to a YAML 1.1
    reader too (a mantissa with a point)."""
    import dataclasses

    cfg = dataclasses.replace(sport_cfg, damper=dataclasses.replace(
        sport_cfg.damper, friction_force_n=value))
    path = tmp_path / "out.yaml"
    save_config(cfg, path)
    assert load_config(path).damper.friction_force_n == value
    written = yaml.safe_load(path.read_text())["/**"]["ros__parameters"]["damper"]
    assert isinstance(written["friction_force_n"], float)
    assert written["friction_force_n"] == value
