"""The project's truth simulation: dyno data of a damper with an effect the paper's model
lacks, for testing and benchmarking ``diagnose``.

The truth is the project's own compressible model with one ``damper.extensions`` group
switched on (:mod:`damper_emulator.model.extensions`), run over the paper's identification
and validation protocol (docs/model.md §3): a quasi-static triangle, an exponential chirp with
growing velocity amplitude, and the validation sines (1 Hz and 3 Hz at 50 mm, 12 Hz at
5 mm), with Gaussian noise on the force.  :data:`EXAMPLE_EFFECTS` holds one parameter set
per family (chosen by us: visible in the protocol, physically plausible); nothing in the
files says which effect is in them.

The same data come from the command line with a params file holding the extension:
``damper-hil dyno --params truth.yaml --protocol ...``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from damper_emulator.acquisition.chain import record_channel
from damper_emulator.acquisition.rig import RigParams
from damper_emulator.diagnose.truth_series import Series, series_starts
from damper_emulator.dyno import protocols
from damper_emulator.dyno.measured import MeasuredData, write_measured_csv
from damper_emulator.dyno.simulated import sine_file_name
from damper_emulator.model.compressible import DamperModel, simulate
from damper_emulator.params import ModelConfig, load_config, with_extensions


@dataclass(frozen=True)
class RandomDrive:
    """A random road as a dyno replays it: the damper's stroke as a sum of
    :attr:`components` sines at frequencies spaced logarithmically from :attr:`f_low_hz`
    to :attr:`f_high_hz`, each of the same velocity amplitude (a velocity spectrum flat
    over the band, as between a car's body and wheel-hop modes) and a random phase, scaled
    to the velocity r.m.s. :attr:`velocity_rms_m_s`; the velocity is the stroke's exact
    derivative.  The defaults (2–15 Hz, 0.25 m/s r.m.s.) peak near ±35 mm, within the
    speed programme's quasi-static test."""

    duration_s: float = 20.0
    rate_hz: float = 1000.0
    f_low_hz: float = 2.0
    f_high_hz: float = 15.0
    velocity_rms_m_s: float = 0.25
    components: int = 200
    seed: int = 7

    def history(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(t, x, v)`` of the drive."""
        rng = np.random.default_rng(self.seed)
        f = np.geomspace(self.f_low_hz, self.f_high_hz, self.components)
        phase = rng.uniform(0.0, 2.0 * np.pi, f.size)
        t = np.arange(int(round(self.duration_s * self.rate_hz)) + 1) / self.rate_hz
        # equal velocity amplitudes a·2πf: r.m.s. a·2π·sqrt(N/2)
        a = self.velocity_rms_m_s / (2.0 * np.pi * np.sqrt(f.size / 2.0))
        arg = 2.0 * np.pi * np.outer(t, f) + phase
        x = (np.sin(arg) * (a / f)).sum(axis=1)
        v = (np.cos(arg) * (2.0 * np.pi * a)).sum(axis=1)
        return t, x - x[0], v


#: the name of the random road's file
ROAD_FILE = "road.csv"


@dataclass(frozen=True)
class Protocol:
    """The dyno protocol of a diagnosis: identification files (fit) and held-out files.
    Defaults: the paper's (docs/model.md §3) as the virtual dyno runs them
    (:mod:`damper_emulator.dyno.protocols`: quasi-static 4 mm/s over ±75 mm twice, 150 s;
    chirp 0.5–16 Hz in 60 s at 0.05–1.5 m/s; the three validation sines held out).

    The other programme (:data:`SPEED_PROGRAMME`): the quasi-static test and a
    peak-velocity series of sines (:attr:`speeds`, one file each) identified together, a
    random road (:attr:`road`) held out."""

    quasi_static: protocols.QuasiStatic = protocols.QuasiStatic()
    #: the chirp (``None``: none)
    chirp: protocols.Chirp | None = protocols.Chirp()
    #: a peak-velocity series of sines, one identification file per speed (``None``: none)
    speeds: protocols.FourteenSpeed | None = None
    #: validation sines: (frequency [Hz], amplitude [m])
    sines: tuple[tuple[float, float], ...] = protocols.PAPER_SINES
    #: recorded cycles, sample rate and lead-in of each validation sine (and speed sine)
    sine: protocols.Sine = protocols.Sine()
    #: a random road held out (``None``: none)
    road: RandomDrive | None = None

    @property
    def n_fit(self) -> int:
        """How many of :meth:`histories`' files are identification files (the first)."""
        return (1 + (self.chirp is not None)
                + (self.speeds.points if self.speeds is not None else 0))

    def oversampled(self, factor: int) -> Protocol:
        """The same tests sampled ``factor`` times faster (the truth's grid under a rig's
        analog filters: :func:`simulate_session`)."""
        q, c, s, p, r = self.quasi_static, self.chirp, self.sine, self.speeds, self.road
        return dataclasses.replace(
            self, quasi_static=dataclasses.replace(q, rate_hz=q.rate_hz * factor),
            chirp=dataclasses.replace(c, rate_hz=c.rate_hz * factor) if c else None,
            speeds=dataclasses.replace(p, rate_hz=p.rate_hz * factor) if p else None,
            sine=dataclasses.replace(s, rate_hz=s.rate_hz * factor),
            road=dataclasses.replace(r, rate_hz=r.rate_hz * factor) if r else None)

    def histories(self) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """``{file name: (t, x, v)}`` of every test, identification files first."""
        q, c, s, p = self.quasi_static, self.chirp, self.sine, self.speeds
        out = {"quasi_static.csv": protocols.quasi_static(
                   q.velocity_m_s, q.amplitude_m, q.cycles, q.rate_hz)}
        if c is not None:
            out["chirp.csv"] = protocols.chirp(c.f_start_hz, c.f_end_hz, c.duration_s,
                                               c.v_start_m_s, c.v_end_m_s, c.rate_hz)
        if p is not None:
            freqs = protocols.fourteen_speed_frequencies(p.points, p.amplitude_m,
                                                         p.v_min_m_s, p.v_max_m_s)
            for k, f in enumerate(freqs, 1):
                out[speed_file_name(k)] = protocols.sine(
                    float(f), p.amplitude_m, p.cycles, p.rate_hz,
                    start_cycles=s.settle_cycles)
        for f, a in self.sines:
            out[sine_file_name(f)] = protocols.sine(f, a, s.cycles, s.rate_hz,
                                                    start_cycles=s.settle_cycles)
        if self.road is not None:
            out[ROAD_FILE] = self.road.history()
        return out


def speed_file_name(k: int) -> str:
    """The file of the ``k``-th (from 1) speed of a peak-velocity series."""
    return f"speed_{k:02d}.csv"


def has_lead_in(name: str) -> bool:
    """Whether the file ``name`` is a sine recorded after a lead-in (dropped)."""
    return name.startswith(("sine_", "speed_"))


#: The other test programme: the quasi-static test over ±35 mm and ten peak-velocity
#: sines of ±25 mm from 0.05 to 1.2 m/s (two cycles each) identified together, a random
#: road of 20 s held out.
SPEED_PROGRAMME = Protocol(
    quasi_static=protocols.QuasiStatic(amplitude_m=0.035),
    chirp=None, speeds=protocols.FourteenSpeed(points=10, v_min_m_s=0.05, v_max_m_s=1.2),
    sines=(), road=RandomDrive())


#: Temperature [°C] the thermal example's thermocouple reads: per file, a function of the
#: time in that file (the chirp heats the damper; the sines follow, warmer).
THERMAL_SESSION_C: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "quasi_static.csv": lambda t: np.full_like(t, 25.0),
    "chirp.csv": lambda t: 25.0 + 25.0 * (t - t[0]) / max(t[-1] - t[0], 1e-9),
}
#: Temperature of the sines of the thermal example, in protocol order [°C].
THERMAL_SINE_TEMPERATURES_C = (55.0, 65.0, 45.0)


#: One example per family: ``{extension name: parameters}`` (see ``ExtensionParams``), plus
#: base-parameter changes some need: the cavitation example's gas charge is low enough for
#: the compression valve to pull the rebound chamber down to the vapour pressure, and the
#: gas-spring example's gas volume small enough for its spring to matter (the sport
#: damper's gas force changes by only ~10 N between adiabatic and isothermal at 60 mm).
#: The bypass groove (−3 … +13 mm) is shorter than the chirp's stroke (±16 mm), as the
#: ride-height zone of a position-sensitive damper: a groove longer than the
#: identification's stroke acts on the whole chirp and cannot be told from a valve bleed
#: in those files (docs/diagnose.md, limits).
EXAMPLE_EFFECTS: dict[str, dict[str, Any]] = {
    "lugre_friction": {"params": {"coulomb_n": 43.7, "static_n": 90.0,
                                  "stribeck_velocity_m_s": 0.01,
                                  "bristle_stiffness_n_m": 1.5e5}},
    "viscosity_temperature": {"params": {"temperature_coefficient_per_k": 0.03,
                                         "reference_temperature_c": 25.0}},
    "cavitation": {"params": {"cavitation_pressure_pa": 2.0e4},
                   "base": {"gas_pressure_static_pa": 1.5e6}},
    "valve_lag": {"params": {"time_constant_s": 4e-3}},
    "series_compliance": {"params": {"stiffness_n_m": 1.5e6}},
    "end_stops": {"params": {"rebound_position_m": 0.04, "compression_position_m": -0.042,
                             "stiffness_n_m2": 4.0e6}},
    "air_entrainment": {"params": {"air_volume_fraction": 0.02}},
    "bypass_groove": {"params": {"area_m2": 2.0e-6, "center_m": 0.005,
                                 "half_length_m": 0.008}},
    "gas_heat_transfer": {"params": {"thermal_time_constant_s": 0.3},
                          "base": {"gas_volume_static_m3": 3.0e-5}},
}


#: A discovered term (``damper.extensions.discovered_term``) for the tests of the
#: extension schema and of the step: a 6 kg mass and damping over a 10 mm zone.
EXAMPLE_TERM: dict[str, float] = {"acceleration_kg": 6.0, "profile_n_s_m": 800.0,
                                  "profile_center_m": 0.01, "profile_width_m": 0.005}


#: The ``inertia`` extension for the tests of its schema and of the step: 6 kg.  The truth
#: of an inertia in the benchmark and the diagnosis tests is a force of its own
#: (``m dv/dt`` on the truth's grid), not the extension the model runs.
EXAMPLE_INERTIA: dict[str, float] = {"mass_kg": 6.0}


def example_params(name: str) -> Mapping[str, Any]:
    """The example parameters of the extension ``name``: a library effect's
    (:data:`EXAMPLE_EFFECTS`), the inertia's (:data:`EXAMPLE_INERTIA`) or the discovered
    term's (:data:`EXAMPLE_TERM`)."""
    if name == "inertia":
        return EXAMPLE_INERTIA
    return EXAMPLE_TERM if name == "discovered_term" else EXAMPLE_EFFECTS[name]["params"]


def with_extension(cfg: ModelConfig, name: str | None, params: Mapping[str, Any] | None = None,
                   base_changes: Mapping[str, Any] | None = None) -> ModelConfig:
    """``cfg`` with one extension (``None``: none) set to ``params`` and the damper's base
    parameters changed by ``base_changes``; validated."""
    return with_extensions(cfg, {name: params or {}} if name is not None else {},
                           base_changes)


def example_config(name: str | Sequence[str] | None, base: ModelConfig | None = None
                   ) -> ModelConfig:
    """The truth configuration of :data:`EXAMPLE_EFFECTS` ``[name]`` (or of several names
    together) on ``base`` (default ``config/sport.yaml``); ``None``: the base model."""
    base = base if base is not None else load_config()
    names = [] if name is None else [name] if isinstance(name, str) else list(name)
    return with_extensions(base, {n: EXAMPLE_EFFECTS[n]["params"] for n in names},
                           example_base_changes(names))


def example_base_changes(names: Sequence[str]) -> dict[str, Any]:
    """The base-parameter changes of the examples ``names`` (merged)."""
    out: dict[str, Any] = {}
    for n in names:
        out.update(EXAMPLE_EFFECTS[n].get("base", {}))
    return out


def session_temperatures(name: str, t: np.ndarray, sine_index: int | None) -> np.ndarray:
    """The thermocouple reading of the thermal example session in file ``name`` (a
    speed series warms as the chirp does, by its speed; the road is as warm as the
    warmest sine)."""
    if name in THERMAL_SESSION_C:
        return THERMAL_SESSION_C[name](t)
    if name.startswith("speed_"):
        k = int(name[len("speed_"):].split(".")[0])
        return np.full_like(t, 25.0 + 2.5 * (k - 1))
    if name == ROAD_FILE:
        return np.full_like(t, max(THERMAL_SINE_TEMPERATURES_C))
    temps = THERMAL_SINE_TEMPERATURES_C
    return np.full_like(t, temps[(sine_index or 0) % len(temps)])


@dataclass(frozen=True)
class ModelForm:
    """How the truth differs in model form from the emulator's model, as a real damper
    does: nothing by default.

    ``friction_smoothing_m_s``: eq 4's Coulomb switch ``F_fr sgn(ẋ)`` becomes the smooth
    ``F_fr tanh(ẋ / v_f)`` (every real seal has a finite pre-sliding slope; not with LuGre
    friction in the truth, which is smooth already).  ``integrator_refinement``: the truth
    is integrated on sub-steps this many times shorter than the emulator's.
    ``displacement_noise_m``: white noise on the recorded displacement (the velocity column
    stays the dyno's own, clean)."""

    friction_smoothing_m_s: float = 0.0
    integrator_refinement: int = 1
    displacement_noise_m: float = 0.0


#: The model-form difference of the benchmark and the tests: a 5 mm/s friction smoothing
#: and 5 µm displacement noise.
REALISTIC = ModelForm(friction_smoothing_m_s=0.005, displacement_noise_m=5e-6)
#: ... and a 4× finer integrator, the benchmark's truth (a damper is continuous: with a
#: valve lag and a cavity the model on the data sheet's 0.5 ms sub-steps is about 20 N
#: r.m.s. on the chirp off the same on 0.125 ms, which no parameter of the model removes).
REALISTIC_FINE = ModelForm(friction_smoothing_m_s=0.005, integrator_refinement=4,
                           displacement_noise_m=5e-6)


#: The truth under a rig's analog filters is simulated this many times faster than the
#: files are sampled, filtered on that grid and sampled from it (the filters act on the
#: force between the samples, as an analog filter does).
RIG_OVERSAMPLING = 4


def simulate_session(cfg: ModelConfig, protocol: Protocol | None = None,
                     noise_std_n: float = 5.0, seed: int = 0, temperature: bool = False,
                     extra_force: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
                     | None = None, form: ModelForm = ModelForm(),
                     rig: RigParams | None = None, series: Series | None = None
                     ) -> dict[str, MeasuredData]:
    """Run ``cfg`` over the protocol: ``{file name: MeasuredData}``, identification files
    first.

    Parameters
    ----------
    cfg : ModelConfig
        The truth (e.g. :func:`example_config`).
    noise_std_n : float
        Standard deviation of the white Gaussian noise added to the force [N].
    seed : int
        Noise seed.
    temperature : bool
        Give every file the temperature column of the thermal example session
        (:data:`THERMAL_SESSION_C`), which also drives the truth's viscosity.
    extra_force : callable, optional
        ``f(t, x, v) -> force [N]`` added to the truth's force: an effect outside the
        extension library.
    form : ModelForm
        Model-form differences from the emulator's model (default none).
    rig : RigParams, optional
        The rig's measurement chain: the truth is simulated :data:`RIG_OVERSAMPLING`
        times faster than the files are sampled; force, displacement and velocity go
        through their channels (:func:`damper_emulator.acquisition.record_channel`: filter,
        skew, sampling, the noise, the converter; the velocity is not quantised, the
        dyno derives it).  The files do not carry the chain: a user gives it (``--rig``)
        or the diagnosis estimates it.
    series : Series, optional
        How the files follow each other (:mod:`damper_emulator.diagnose.truth_series`):
        the rig's faults on the series clock, the damper's changes per file, the oil's
        temperature per file.
    """
    protocol = protocol or Protocol()
    coarse = protocol.histories()
    if rig is not None:
        protocol = protocol.oversampled(RIG_OVERSAMPLING)
    if form.integrator_refinement > 1:
        cfg = dataclasses.replace(cfg, numerics=dataclasses.replace(
            cfg.numerics,
            max_substep_s=cfg.numerics.max_substep_s / form.integrator_refinement))
    series = series or Series()
    model = DamperModel(cfg)
    lugre = (cfg.damper.extensions is not None
             and cfg.damper.extensions.lugre_friction is not None)
    f_fr = cfg.damper.friction_force_n
    smooth = form.friction_smoothing_m_s if not lugre else 0.0
    rng = np.random.default_rng(seed)
    out: dict[str, MeasuredData] = {}
    sine_index = 0
    histories = protocol.histories()
    starts = series_starts([t[-1] - (max(t[0], 0.0) if has_lead_in(n) else t[0])
                            for n, (t, _, _) in histories.items()], series.gap_s)
    phases = rng.uniform(0.0, 2.0 * np.pi, len(series.faults.lines))
    for index, (name, (t, x, v)) in enumerate(histories.items()):
        is_sine = name.startswith("sine_")
        lead_in = has_lead_in(name)
        temp = None
        if series.oil_temperatures_c is not None:
            temp = np.full_like(t, series.oil_temperatures_c[index])
        elif temperature:
            temp = session_temperatures(name, t, sine_index if is_sine else None)
        file_model = model
        if series.changes is not None:
            file_model = DamperModel(dataclasses.replace(cfg, damper=dataclasses.replace(
                cfg.damper, **series.changes(index))))
        res = simulate(file_model, t, x, v, temperature_c=temp)
        f = res.force_n
        if extra_force is not None:
            f = f + extra_force(t, x, v)
        if smooth > 0.0:  # the smooth friction in place of eq 4's switch
            f = f + f_fr * (np.tanh(v / smooth) - np.sign(v))
        if not series.faults.does_nothing:  # the rig's amplifier, on the series clock
            t_series = starts[index] + t - (0.0 if lead_in else t[0])
            f = series.faults.apply(t_series, f, phases)
        if not series.temperature_column:
            temp = None
        if rig is not None:  # through the rig's channels, at the files' sample times
            tc = coarse[name][0]
            velocity_channel = dataclasses.replace(rig.displacement, adc_bits=0)
            f = record_channel(t, f, rig.force, tc, noise_std_n, rng)
            x, v = (record_channel(t, x, rig.displacement, tc),
                    record_channel(t, v, velocity_channel, tc))
            temp = np.interp(tc, t, temp) if temp is not None else None
            t = tc
        if lead_in:  # drop the lead-in: the record starts at t = 0
            k = int(np.searchsorted(t, 0.0))
            t, x, v, f = t[k:], x[k:], v[k:], f[k:]
            temp = temp[k:] if temp is not None else None
            sine_index += is_sine
        if rig is None and noise_std_n > 0:
            f = f + rng.normal(0.0, noise_std_n, f.size)
        if form.displacement_noise_m > 0:
            x = x + rng.normal(0.0, form.displacement_noise_m, x.size)
        out[name] = MeasuredData(time=t, displacement=x, force=f, velocity=v,
                                 temperature=temp, name=name, path=name)
    return out


def write_session(data: Mapping[str, MeasuredData], out_dir: str | Path) -> dict[str, Path]:
    """Write a session's files as measured-data CSVs into ``out_dir``; their paths by name."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    for name, d in data.items():
        paths[name] = write_measured_csv(out / name, d.time, d.displacement, d.force,
                                         d.velocity, d.temperature)
    return paths
