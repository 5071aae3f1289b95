"""What the diagnosis tests share: the truth's shorter protocol, the sessions, identify
then diagnose (tests/test_diagnose.py, tests/test_diagnose_discovery.py,
tests/test_diagnose_families.py)."""

from __future__ import annotations

import dataclasses
import math

from damper_emulator.diagnose.selection import diagnose
from damper_emulator.diagnose.truth import REALISTIC, Protocol, example_config, simulate_session
from damper_emulator.dyno.protocols import Chirp, QuasiStatic
from damper_emulator.identify.pipeline import identify
from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import load_config

#: a shorter chirp and one quasi-static cycle keep the suite quick; the rest as the paper
PROTOCOL = Protocol(chirp=Chirp(duration_s=8.0), quasi_static=QuasiStatic(cycles=1))
#: a longer chirp where a test asks more of each file: whether a discovered term is one
#: over the files (on the 8 s chirp one file determines a mass of the other sign)
LONGER_PROTOCOL = dataclasses.replace(PROTOCOL, chirp=Chirp(duration_s=12.0))
NOISE_N = 4.0
#: joint-fit evaluations where a test compares two runs rather than the fit's result
FEW_NFEV = 6
#: for each single effect, two candidates that take part of it when it is absent
CONFUSABLE = {
    "lugre_friction": ("end_stops", "valve_lag"),
    "viscosity_temperature": ("valve_lag", "gas_heat_transfer"),
    "cavitation": ("air_entrainment", "series_compliance"),
    "valve_lag": ("series_compliance", "air_entrainment"),
    "series_compliance": ("valve_lag", "air_entrainment"),
    "end_stops": ("gas_heat_transfer", "bypass_groove"),
    "air_entrainment": ("series_compliance", "cavitation"),
    "bypass_groove": ("end_stops", "lugre_friction"),
    "gas_heat_transfer": ("end_stops", "air_entrainment"),
}
#: relative tolerance on the main recovered parameters (identification from the same
#: data and a truth of another model form: the parameters are close, not exact)
PARAMETER_TOLERANCE = 0.25
#: the parameters checked (the others are weakly determined on the short protocol)
CHECKED = {"lugre_friction": ("coulomb_n",), "cavitation": (),
           "viscosity_temperature": ("temperature_coefficient_per_k",),
           "end_stops": ("rebound_position_m", "compression_position_m"),
           "bypass_groove": ("center_m", "half_length_m")}


def truth_session(effects, damper="sport", seed=3, extra_force=None, chain_given=True,
                  protocol=PROTOCOL):
    """The data sheet and the files.  The truth's files are recorded raw, and with
    ``chain_given`` the test says so (``--rig`` of a rig without filter): the diagnosis
    then does not estimate the rig's delay, one fit fewer per round (the tests of the
    estimated chain are the load-cell filter's, the inertia's and the command line's)."""
    from damper_emulator.acquisition.rig import RigParams

    sheet = load_config(f"config/{damper}.yaml")
    truth = example_config(effects, sheet)
    data = list(simulate_session(truth, protocol, noise_std_n=NOISE_N, seed=seed,
                                 temperature=True, extra_force=extra_force,
                                 form=REALISTIC).values())
    if chain_given:
        data = [dataclasses.replace(d, acquisition=RigParams()) for d in data]
    return sheet, data


def identify_and_diagnose(sheet, data, effects=None, **kw):
    cfg = identify(data[0], data[1], sheet).config
    return diagnose(DamperModel(cfg), data[:2], data[2:], effects, jobs=2, **kw)


def pooled(rms: dict[str, float], names) -> float:
    return math.sqrt(sum(rms[n] ** 2 for n in names) / len(names))


