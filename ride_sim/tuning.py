"""Virtual damper tuning (the paper's motive): valve designs evaluated on the
quarter car, their Pareto front and what moves it (docs/tune.md).

**Design space.**  Per valve direction, the blow-off preload ``Δp0`` and spring rate
``K_spring`` (eq 10), the leak ``K_leak`` (eq 9) and the port restriction ``K_port``
(eq 8), and optionally the adaptive damper's two bypass diameters: each as a factor of the
base damper's value between the bounds of :class:`~ride_sim.params.TuneBounds`
(log-uniform: a valve constant is as likely halved as doubled).  A design is a point of
the unit hypercube (:func:`design_config` maps it to a damper).

**Objectives** (all minimised; :func:`evaluate`): over the random roads of
:class:`~ride_sim.params.TuneSettings` (ISO 8608 classes at a speed), the mean of

* ``accel_w_rms``: ISO 2631-1 Wk-weighted body acceleration r.m.s. [m/s²] (comfort);
* ``dtl_rms``: dynamic tyre load r.m.s. [N] (road holding);
* ``sws_rms``: suspension working space r.m.s. [m] (packaging);

each road driven after a lead-in of the same periodic road, as the ride studies do
(:func:`ride_sim.study_runs.random_road_input`).  **Constraint**: the peak SWS over every
road and the pothole (the ride studies', :func:`ride_sim.study_runs.pothole_input`) within
the suspension's travel, bump and rebound.  A design whose damper raised a fault bit is
infeasible too.

**Pareto front**: the feasible designs no other feasible design beats in every objective
(:func:`pareto_mask`).  **Sensitivity**: Spearman's rank correlation of each design
variable (its log factor) with each objective over every design evaluated
(:func:`sensitivity`): a global, monotone measure, robust to the objectives' scales.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import AdaptiveParams, ModelConfig, validate
from damper_emulator.schema import ParameterError, build_group, check_value, node_parameters
from ride_sim.many import simulate_many
from ride_sim.params import BYPASS_KEYS, QuarterCarParams, RoadParams, TuneBounds, TuneSettings
from ride_sim.road_synthesis import iso8608_class
from ride_sim.study_runs import history_metrics, pothole_input, random_road_input, start_state

#: the objectives, in order, with their units (all minimised)
OBJECTIVES = (("accel_w_rms", "m/s²", "comfort: Wk-weighted body acceleration r.m.s."),
              ("dtl_rms", "N", "road holding: dynamic tyre load r.m.s."),
              ("sws_rms", "m", "packaging: suspension working space r.m.s."))


@dataclass(frozen=True)
class TuneSpec:
    """What ``tune`` runs: its settings and the design space's bounds."""

    settings: TuneSettings = TuneSettings()
    bounds: TuneBounds = TuneBounds()

    @property
    def variables(self) -> tuple[str, ...]:
        return self.settings.variables()

    def log_bounds(self) -> np.ndarray:
        """``(variables, 2)``: the natural logs of each variable's factor bounds."""
        out: np.ndarray = np.log(np.array([getattr(self.bounds, v) for v in self.variables],
                                          dtype=float))
        return out


def spec_from_mapping(doc: Any, where: str, **overrides: Any) -> TuneSpec:
    """The ``tune`` group of a params file (``tune: {..., bounds: {...}}``, at the top or
    under a node's ``ros__parameters``; ``None``: every default), with ``overrides`` of
    settings (e.g. from the command line), checked."""
    group: dict[str, Any] = {}
    if doc is not None:
        group = dict(node_parameters(doc, where, "tune")["tune"] or {})
    bounds = build_group(TuneBounds, group.pop("bounds", None) or {}, "tune.bounds", where,
                         check_value)
    group.update({k: v for k, v in overrides.items() if v is not None})
    settings = build_group(TuneSettings, group, "tune", where, check_value)
    spec = TuneSpec(settings, bounds)
    check_spec(spec, where)
    return spec


def check_spec(spec: TuneSpec, where: str) -> None:
    """Cross rules: known road classes; bounds ``low ≤ high``."""
    classes = spec.settings.classes()
    if not classes:
        raise ParameterError(f"{where}: tune.road_classes names no class")
    for c in classes:
        iso8608_class(c)  # RoadError for an unknown class
    for v in spec.variables:
        lo, hi = getattr(spec.bounds, v)
        if not 0.0 < lo <= hi:
            raise ParameterError(f"{where}: tune.bounds.{v} must be 0 < low <= high, got "
                                 f"[{lo:g}, {hi:g}]")


def check_base(base: ModelConfig, spec: TuneSpec, where: str) -> None:
    """The base damper can carry the design space (a bypass to tune when ``bypass``)."""
    if spec.settings.bypass and base.damper.adaptive is None:
        raise ParameterError(f"{where}: tune.bypass needs a base damper with a "
                             "damper.adaptive group (a bypass to size)")


def factors_of(unit: np.ndarray, spec: TuneSpec) -> np.ndarray:
    """Unit-hypercube points ``(m, p)`` → factors of the base values (log-uniform)."""
    lb = spec.log_bounds()
    out: np.ndarray = np.exp(lb[:, 0] + np.clip(unit, 0.0, 1.0) * (lb[:, 1] - lb[:, 0]))
    return out


def design_config(base: ModelConfig, factors: Sequence[float], spec: TuneSpec
                  ) -> ModelConfig:
    """The base damper with its tuned constants multiplied by ``factors``; validated."""
    d = base.damper
    change: dict[str, dict[str, float]] = {"rebound": {}, "compression": {}, "adaptive": {}}
    for name, f in zip(spec.variables, factors):
        if name in BYPASS_KEYS:
            change["adaptive"][name] = getattr(d.adaptive, name) * float(f)
        else:
            side, key = name.split("_", 1)
            change[side][key] = getattr(getattr(d, side), key) * float(f)
    adaptive: AdaptiveParams | None = d.adaptive
    if change["adaptive"] and adaptive is not None:
        adaptive = dataclasses.replace(adaptive, **change["adaptive"])
    damper = dataclasses.replace(
        d, rebound=dataclasses.replace(d.rebound, **change["rebound"]),
        compression=dataclasses.replace(d.compression, **change["compression"]),
        adaptive=adaptive)
    cfg = dataclasses.replace(base, damper=damper)
    validate(cfg)
    return cfg


@dataclass(frozen=True)
class Road:
    """One road of the evaluation: heights at the samples and the evaluated window."""

    name: str
    heights: np.ndarray
    start: int
    stop: int
    #: whether its r.m.s. values count in the objectives (the pothole: constraint only)
    objective: bool


def roads(settings: TuneSettings, road: RoadParams, dt_s: float) -> list[Road]:
    """The random roads (one per class) and, with ``pothole``, the pothole."""
    out = []
    for k, c in enumerate(settings.classes()):
        rough = iso8608_class(c)
        params = dataclasses.replace(road, roughness=rough.roughness,
                                     waviness=rough.waviness, length_m=settings.length_m,
                                     band_cycles_per_m=settings.band_cycles_per_m,
                                     lead_in_s=settings.lead_in_s)
        heights, n_lead, n_eval = random_road_input(params, settings.speed_m_s,
                                                    settings.seed + k, dt_s,
                                                    settings.band_cycles_per_m)
        out.append(Road(f"ISO 8608 class {c} at {settings.speed_m_s:g} m/s", heights,
                        n_lead, n_lead + n_eval, True))
    if settings.pothole:
        heights = pothole_input(road, road.pothole_speed_m_s, dt_s)[2]
        out.append(Road(f"pothole at {road.pothole_speed_m_s:g} m/s", heights, 0,
                        heights.size, False))
    return out


#: columns of :func:`evaluate`'s result: the objectives, then
#: peak bump and rebound SWS [m] (rebound as a positive travel), fault bits, feasible
EVAL_COLUMNS = (*(o[0] for o in OBJECTIVES), "sws_peak_bump", "sws_peak_rebound", "faults",
                "feasible")


def evaluate(base: ModelConfig, factors: np.ndarray, spec: TuneSpec,
             car: QuarterCarParams, road_list: Sequence[Road], dt_s: float) -> np.ndarray:
    """Objectives and constraint of the designs ``factors`` ``(m, p)``: an ``(m,
    len(EVAL_COLUMNS))`` array (module docstring), all designs of a road in one
    :func:`ride_sim.many.simulate_many`.  A design the damper's rules refuse (e.g. a
    normal bypass wider than the comfort one) is infeasible, its values NaN."""
    settings = spec.settings
    rows = np.atleast_2d(factors)
    valid = np.ones(rows.shape[0], bool)
    models = []
    for j, f in enumerate(rows):
        try:
            models.append(DamperModel(design_config(base, f, spec)))
        except ParameterError:  # a corner of the box the damper's rules exclude
            valid[j] = False
    out = np.full((rows.shape[0], len(EVAL_COLUMNS)), np.nan)
    out[:, EVAL_COLUMNS.index("feasible")] = 0.0
    if models:
        out[valid] = _evaluate_models(models, settings, car, road_list, dt_s)
    return out


def _evaluate_models(models: Sequence[DamperModel], settings: TuneSettings,
                     car: QuarterCarParams, road_list: Sequence[Road], dt_s: float
                     ) -> np.ndarray:
    m = len(models)
    sums = np.zeros((m, len(OBJECTIVES)))
    n_obj = 0
    bump = np.zeros(m)
    reb = np.zeros(m)
    faults = np.zeros(m, dtype=np.int64)
    for r in road_list:
        res = simulate_many(car, models, r.heights, dt_s,
                            initial_state=start_state(r.heights, dt_s))
        faults |= res.faults
        sl = slice(r.start, r.stop)
        bump = np.maximum(bump, res.sws_m[:, sl].max(axis=1))
        reb = np.maximum(reb, -res.sws_m[:, sl].min(axis=1))
        if r.objective:
            n_obj += 1
            for j in range(m):
                met = history_metrics(res.sws_m[j], res.body_accel_m_s2[j], res.dtl_n[j],
                                      dt_s, r.start, r.stop)
                sums[j] += [met[o[0]] for o in OBJECTIVES]
    feasible = ((bump <= settings.bump_travel_m) & (reb <= settings.rebound_travel_m)
                & (faults == 0))
    return np.column_stack([sums / max(n_obj, 1), bump, reb, faults.astype(float),
                            feasible.astype(float)])


def pareto_mask(objectives: np.ndarray, feasible: np.ndarray | None = None) -> np.ndarray:
    """Boolean mask of the non-dominated rows of ``objectives`` ``(m, k)`` (minimised)
    among the ``feasible`` ones: no other feasible row is ≤ in every objective and < in
    one.  Duplicated rows are all kept."""
    f = np.asarray(objectives, dtype=float)
    ok = np.ones(f.shape[0], bool) if feasible is None else np.asarray(feasible, bool)
    mask = np.zeros(f.shape[0], bool)
    idx = np.flatnonzero(ok)
    for i in idx:
        others = f[idx]
        dominated = np.any(np.all(others <= f[i], axis=1) & np.any(others < f[i], axis=1))
        mask[i] = not dominated
    return mask


def sensitivity(factors: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Spearman's rank correlation of each variable (column of ``factors``) with each
    objective (column of ``values``): ``(variables, objectives)``, in [−1, 1], over the
    rows whose values are finite."""
    from scipy.stats import spearmanr

    p = factors.shape[1]
    ok = np.all(np.isfinite(values), axis=1)
    rho = np.asarray(spearmanr(np.log(factors[ok]), values[ok]).statistic)
    return rho[:p, p:]


def refine(front_unit: np.ndarray, count: int, step: float, rng: np.random.Generator
           ) -> np.ndarray:
    """``count`` new unit-hypercube points around the front's: each a front point
    (in turn) moved by a normal step of ``step`` per variable, kept inside the cube."""
    base = front_unit[np.arange(count) % front_unit.shape[0]]
    out: np.ndarray = np.clip(base + rng.normal(0.0, step, base.shape), 0.0, 1.0)
    return out


def knee(objectives: np.ndarray, mask: np.ndarray) -> int:
    """The front's design nearest the utopia point after scaling each objective to the
    front's range (index into ``objectives``)."""
    idx = np.flatnonzero(mask)
    f = objectives[idx]
    lo, hi = f.min(axis=0), f.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    d = np.sqrt((((f - lo) / span) ** 2).sum(axis=1))
    return int(idx[int(np.argmin(d))])


def dominates_baseline(objectives: np.ndarray, baseline: np.ndarray) -> np.ndarray:
    """Rows no worse than the baseline in every objective and better in one."""
    out: np.ndarray = (np.all(objectives <= baseline, axis=1)
                       & np.any(objectives < baseline, axis=1))
    return out


def describe(settings: TuneSettings) -> str:
    """One line: designs, rounds, roads."""
    rounds = (f", {settings.refine_rounds} refinement rounds of {settings.refine_designs}"
              if settings.refine_rounds else "")
    return (f"{settings.designs} Sobol designs{rounds}; roads: ISO 8608 "
            f"{', '.join(settings.classes())} at {settings.speed_m_s:g} m/s, "
            f"{settings.length_m:g} m each" + (" + pothole" if settings.pothole else ""))


def sobol(count: int, dims: int, seed: int) -> np.ndarray:
    """``count`` scrambled Sobol points in the unit hypercube (scipy.stats.qmc); a count
    that is not a power of two is the first ``count`` of the next power's sequence."""
    from scipy.stats import qmc

    m = max(0, math.ceil(math.log2(max(count, 1))))
    points: np.ndarray = qmc.Sobol(dims, scramble=True, seed=seed).random_base2(m)
    return points[:count]
