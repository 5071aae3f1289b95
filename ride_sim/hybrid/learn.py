"""The twin learns the specimen: a characterisation on the rig before the ride.

A real damper never equals its model.  The host's prediction runs the twin over the
horizon, and the measured force corrects it only below ``force_correction_hz``
(:mod:`ride_sim.hybrid.compensator`): the further the twin is from the specimen, the worse
the rig tracks.  :func:`learn_twin` makes the twin the specimen's, as a test engineer
would, with the project's own tools:

1. **Characterise.**  A quasi-static test (constant velocity, docs/model.md §3) and a chirp
   (:class:`LearnParams`) run on the specimen through ``engine``: on a dyno, the
   :class:`~can_bridge.dyno_rig.RigEngine` (the transfer system identified and
   compensated, the safety layer throughout).  The measured data are written as the
   ``dyno`` command writes them (``quasi_static.csv``, ``chirp.csv``).
2. **Identify** the paper's parameters (gas spring, friction, both valves) from them
   (:func:`damper_emulator.identify.pipeline.identify`), starting from the twin's file.
3. **Compare**: the twin before and after, each simulated on the measured motion of both
   files (eq 34, 35 of the validation), and write the learned parameter file
   (``twin_learned.yaml``, usable by ``emulate``, ``hybrid --twin`` and ``diagnose``).

The comparison is on the data the twin learned from; the ride is the held-out test
(``hybrid.json``'s ``twin`` residual over the ride).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from damper_emulator.dyno import protocols
from damper_emulator.dyno.measured import read_measured_csv, write_measured_csv
from damper_emulator.dyno.protocols import Chirp, QuasiStatic
from damper_emulator.dyno.simulated import check_travel, measured_samples
from damper_emulator.errors import UserError
from damper_emulator.identify.pipeline import identify
from damper_emulator.identify.quasi_static import IdentificationError
from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import save_config
from damper_emulator.validation import validate_file
from ride_sim.hybrid.params import LearnParams, SafetyParams
from ride_sim.hybrid.safety import RunStopped

#: The learned parameter file, in the characterisation's directory.
LEARNED_FILE = "twin_learned.yaml"


@dataclass
class LearnedTwin:
    """What :func:`learn_twin` did: the learned twin, its parameter file, and the twins'
    force residuals before and after on each characterisation file."""

    model: DamperModel
    params_file: Path
    files: list[Path]
    #: per file: ``rms_N`` and ``relative_rms`` of the twin before and after
    before: dict[str, dict[str, float]] = field(default_factory=dict)
    after: dict[str, dict[str, float]] = field(default_factory=dict)
    seconds: float = 0.0

    def to_json(self) -> dict[str, Any]:
        """``hybrid.json``'s ``twin_learning``."""
        return {"params_file": str(self.params_file),
                "files": [str(p) for p in self.files],
                "residual_before": self.before, "residual_after": self.after,
                "seconds": self.seconds}


def check_safe(learn: LearnParams, safety: SafetyParams) -> None:
    """The characterisation within the safety layer's limits, or one line why not (the
    layer would stop it on the rig)."""
    v_max = max(learn.chirp_start_velocity_m_s, learn.chirp_end_velocity_m_s,
                learn.quasi_static_velocity_m_s)
    if v_max > safety.velocity_limit_m_s:
        raise UserError(f"learn: a velocity of {v_max:g} m/s exceeds "
                        f"safety.velocity_limit_m_s {safety.velocity_limit_m_s:g}")
    # the chirp's largest stroke is its start's: v / (2π f)
    x_chirp = learn.chirp_start_velocity_m_s / (2.0 * math.pi * learn.chirp_band_hz[0])
    x_max = max(learn.quasi_static_amplitude_m, x_chirp)
    if x_max > safety.stroke_limit_m:
        raise UserError(f"learn: a stroke of {x_max:g} m exceeds safety.stroke_limit_m "
                        f"{safety.stroke_limit_m:g}")


def _residuals(model: DamperModel, data: list[Any]) -> dict[str, dict[str, float]]:
    out = {}
    for d in data:
        v = validate_file(model, d)
        out[d.name] = {"rms_n": v["rms_N"], "relative_rms": v["relative_rms"]}
    return out


def _run_test(twin: DamperModel, engine: Any, name: str,
              history: tuple[np.ndarray, np.ndarray, np.ndarray], out: Path,
              attempts: int = 1, say: Callable[[str], None] = lambda msg: None) -> Path:
    """One test's stroke history through ``engine``; its measured data written as
    ``out/NAME.csv`` (the samples the engine measured, as ``dyno`` writes them).  A run
    that the watchdog or a stall of the host stopped (:class:`RunStopped` with
    ``timing``) goes again, ``attempts`` runs in all."""
    t, x, v = history
    check_travel(twin, x, f"learn: the {name} test")
    for attempt in range(1, attempts + 1):
        try:
            result = engine(twin, t, x, v)
            break
        except RunStopped as exc:
            if not exc.timing or attempt == attempts:
                raise
            say(f"learn: the {name} test stopped ({exc}): run {attempt + 1} of at most "
                f"{attempts}")
    t, x, v, force, _ = measured_samples(result, t, x, v)
    return write_measured_csv(out / f"{name}.csv", t, x, force, v)


def learn_twin(twin: DamperModel, learn: LearnParams, out: Path, engine: Any,
               progress: Callable[[str], None] | None = None) -> LearnedTwin:
    """Characterise the specimen through ``engine`` (an
    :data:`~damper_emulator.dyno.simulated.Engine`), identify the twin from it and write
    the learned parameter file into ``out`` (module docstring).

    Raises
    ------
    UserError
        The characterisation leaves the damper's travel, or the identification fails on
        its data (one line).
    ride_sim.hybrid.safety.RunStopped
        The safety layer stopped a test on the rig: for a limit the specimen reached, or
        for the watchdog or a stall of the host ``learn.attempts`` times.
    """
    say = progress or (lambda msg: None)
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    qs = protocols.checked(QuasiStatic, "learn", velocity_m_s=learn.quasi_static_velocity_m_s,
                           amplitude_m=learn.quasi_static_amplitude_m, cycles=1)
    f0, f1 = learn.chirp_band_hz
    chirp = protocols.checked(Chirp, "learn", f_start_hz=f0, f_end_hz=f1,
                              duration_s=learn.chirp_s,
                              v_start_m_s=learn.chirp_start_velocity_m_s,
                              v_end_m_s=learn.chirp_end_velocity_m_s)
    say(f"learn: a quasi-static test, ±{1e3 * qs.amplitude_m:g} mm at "
        f"{1e3 * qs.velocity_m_s:g} mm/s")
    files = [_run_test(twin, engine, "quasi_static", protocols.quasi_static(
        qs.velocity_m_s, qs.amplitude_m, qs.cycles, qs.rate_hz), out, learn.attempts, say)]
    say(f"learn: a chirp, {f0:g}–{f1:g} Hz in {chirp.duration_s:g} s, "
        f"{chirp.v_start_m_s:g}–{chirp.v_end_m_s:g} m/s")
    files.append(_run_test(twin, engine, "chirp", protocols.chirp(
        f0, f1, chirp.duration_s, chirp.v_start_m_s, chirp.v_end_m_s, chirp.rate_hz), out,
        learn.attempts, say))
    data = [read_measured_csv(p) for p in files]
    say("learn: identifying the twin from them")
    try:
        learned = DamperModel(identify(data[0], data[1], twin.cfg, fit_alpha=True).config)
    except IdentificationError as exc:
        raise UserError(f"learn: the twin's identification failed on {out}: {exc}") from None
    params_file = out / LEARNED_FILE
    save_config(learned.cfg, params_file)
    result = LearnedTwin(learned, params_file, files, _residuals(twin, data),
                         _residuals(learned, data), time.perf_counter() - t0)
    for name in result.after:
        say(f"learn: {name}: twin residual {result.before[name]['rms_n']:.0f} → "
            f"{result.after[name]['rms_n']:.0f} N r.m.s.")
    return result
