"""Identification report: the figures a user checks a fit with (PNG).

* ``quasi_static_fit.png`` — measured quasi-static force against stroke with the fitted
  eq 37, and the residual;
* ``valve_fit.png`` — the valve pressure drop against flow used by the chirp fit (hysteresis
  filter, compressibility correction) with the fitted characteristic per direction, and the
  residual against velocity;
* ``chirp_residual.png`` — the residual of the incompressible and of the compressible model
  with the identified parameters on the whole chirp, against time, velocity and stroke.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.dyno.plots import decorate, new_figure, save
from damper_emulator.identify.pipeline import Identification, velocity_of
from damper_emulator.identify.quasi_static import gas_force
from damper_emulator.model.compressible import DamperModel, simulate
from damper_emulator.model.incompressible import incompressible_force
from damper_emulator.model.valve import pressure_drop_array

#: At most this many points of one series are drawn in the chirp residual figure (every
#: k-th sample; the r.m.s. values count every sample).  The figure is 1,210 pixels wide
#: (11 in at 110 dpi): 250,000 points are still about 200 per pixel column, so a long
#: chirp (5 million samples at 20 kHz) looks the same and draws in a fifth of the time.
MAX_PLOT_POINTS = 250_000


def _quasi_static(path: Path, ident: Identification, qs: MeasuredData) -> Path:
    d = ident.config.damper
    v = velocity_of(qs)
    extra = ident.series.get("quasi_static_valve_force_n")
    model = (gas_force(qs.displacement, d.gas_pressure_static_pa, d.gas_volume_static_m3,
                       d.rod_area_m2, d.gas_gamma) + d.friction_force_n * np.sign(v)
             + (extra if extra is not None else 0.0))
    fig = new_figure(11, 4.2)
    ax1, ax2 = fig.subplots(1, 2)
    x_mm = qs.displacement * 1e3
    for sel, label, colour in ((v > 0, "extension", "tab:orange"),
                               (v < 0, "compression", "tab:blue")):
        ax1.plot(x_mm[sel], qs.force[sel], ".", ms=2, color=colour, label=f"measured, {label}")
        order = np.argsort(x_mm[sel])
        ax1.plot(x_mm[sel][order], model[sel][order], "k--", lw=1.2)
    ax1.plot([], [], "k--", label="fitted eq 37 (+ valve force)")
    ax1.set_title(f"Quasi-static fit: P_gas {d.gas_pressure_static_pa / 1e6:.4g} MPa, "
                  f"V_gas {d.gas_volume_static_m3 * 1e6:.4g} cm³, "
                  f"F_friction {d.friction_force_n:.3g} N", fontsize=9)
    decorate(ax1, "displacement [mm] (extension +)", "force [N] (rebound +)")
    moving = v != 0
    ax2.plot(x_mm[moving], (qs.force - model)[moving], ".", ms=2, color="tab:gray")
    ax2.set_title(f"residual: r.m.s. {ident.quasi_static.rms:.2f} N (eq 34)", fontsize=9)
    decorate(ax2, "displacement [mm]", "measured − model [N]", legend=False)
    return save(fig, path)


def _valves(path: Path, ident: Identification, chirp: MeasuredData) -> Path:
    d = ident.config.damper
    q, dp, masks = (ident.series[k] for k in ("flow_m3_s", "pressure_drop_pa", "masks"))
    fig = new_figure(11, 8)
    axes = fig.subplots(2, 2)
    v = velocity_of(chirp)
    for col, side in enumerate(("rebound", "compression")):
        m = masks[side]
        fit = getattr(ident, side)
        qa, dpa = np.abs(q[m]), np.abs(dp[m])
        ax = axes[0, col]
        ax.plot(qa * 1e6, dpa / 1e6, ".", ms=1.5, alpha=0.4, color="tab:gray",
                label=f"chirp samples used ({m.sum()})")
        grid = np.linspace(0, qa.max(), 400)
        ax.plot(grid * 1e6, pressure_drop_array(grid, getattr(d, side),
                                                d.oil_kinematic_viscosity_m2_s) / 1e6,
                "k--", lw=1.5, label="fitted Δp(Q), eqs 8–29")
        ax.set_title(f"{side} valve: r.m.s. {fit.rms:.2f} N, relative "
                     f"{100 * fit.relative_rms:.2f} % (eqs 34–35)", fontsize=9)
        decorate(ax, "valve flow [cm³/s]", "pressure drop [MPa]")
        model = pressure_drop_array(qa, getattr(d, side), d.oil_kinematic_viscosity_m2_s)
        ax = axes[1, col]
        ax.plot(v[m], d.annulus_area_m2 * (dpa - model), ".", ms=1.5, alpha=0.5,
                color="tab:gray")
        decorate(ax, "velocity [m/s]", "residual force [N]", legend=False)
    return save(fig, path)


def _chirp_residual(path: Path, ident: Identification, chirp: MeasuredData) -> Path:
    v = velocity_of(chirp)
    d = ident.config.damper
    rigid = incompressible_force(v, ident.config) - d.static_force_n + gas_force(
        chirp.displacement, d.gas_pressure_static_pa, d.gas_volume_static_m3, d.rod_area_m2,
        d.gas_gamma)
    hysteretic = simulate(DamperModel(ident.config), chirp.time, chirp.displacement, v)
    residuals = (("incompressible model (eqs 30–32)", chirp.force - rigid, "tab:gray"),
                 ("compressible model (eqs 1–4)", chirp.force - hysteretic.force_n,
                  "tab:blue"))
    fig = new_figure(11, 7)
    axes = fig.subplot_mosaic([["t", "t"], ["v", "x"]])
    drawn = slice(None, None, -(-chirp.time.size // MAX_PLOT_POINTS))  # ceiling division
    for label, r, colour in residuals:
        rms = float(np.sqrt(np.mean(r ** 2)))
        axes["t"].plot(chirp.time[drawn], r[drawn], lw=0.4, color=colour,
                       label=f"{label}: r.m.s. {rms:.1f} N")
        axes["v"].plot(v[drawn], r[drawn], ",", color=colour)
        axes["x"].plot(chirp.displacement[drawn] * 1e3, r[drawn], ",", color=colour)
    axes["t"].set_title("whole chirp, measured − model with the identified parameters "
                        "(the hysteresis is what the incompressible model misses)", fontsize=9)
    decorate(axes["t"], "time [s]", "residual [N]")
    decorate(axes["v"], "velocity [m/s]", "residual [N]", legend=False)
    decorate(axes["x"], "displacement [mm]", "residual [N]", legend=False)
    return save(fig, path)


def write_report(out_dir: str | Path, ident: Identification,
                 progress: Callable[[Path], None] | None = None) -> list[Path]:
    """Write the report figures into ``out_dir``.

    The test data are those :func:`identify` used (joined when several files were given).

    Parameters
    ----------
    out_dir : str or Path
        Created if missing.
    ident : Identification
    progress : callable, optional
        Called with the path of each figure as soon as it is written.

    Returns
    -------
    list of Path
        The figures written.
    """
    qs, chirp = ident.series["quasi_static"], ident.series["chirp"]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for draw, name, data in ((_quasi_static, "quasi_static_fit.png", qs),
                             (_valves, "valve_fit.png", chirp),
                             (_chirp_residual, "chirp_residual.png", chirp)):
        paths.append(draw(out / name, ident, data))
        if progress:
            progress(paths[-1])
    return paths
