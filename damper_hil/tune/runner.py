"""The tuning search on the engine (docs/tune.md "Search").

1. The baseline (every factor 1) and ``designs`` scrambled Sobol points of the design space
   (:func:`ride_sim.tuning.sobol`), in chunks of ``chunk`` designs, one Dask task each: a
   task builds the roads once per worker process and runs its designs on each road with
   the many-design kernel.
2. ``refine_rounds`` rounds: ``refine_designs`` new designs around the feasible Pareto
   front of everything so far (each a front design moved by a normal step, the step
   halved every round).

A task that fails is a bug (the designs are valid by construction) and stops the run with
one line; a worker lost mid-task costs only that task (Dask runs it again).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from damper_emulator.params import ModelConfig
from damper_hil.engine import Engine
from damper_hil.fleet.runner import bar
from ride_sim import tuning as tu
from ride_sim.params import QuarterCarParams, RoadParams

Say = Callable[[str], None]


@dataclass(frozen=True)
class EvalTask:
    """One chunk of designs (factors ``(m, p)``) and everything needed to evaluate it."""

    base: ModelConfig
    factors: np.ndarray
    spec: tu.TuneSpec
    car: QuarterCarParams
    road: RoadParams
    dt_s: float


@functools.lru_cache(maxsize=4)
def _roads(spec: tu.TuneSpec, road: RoadParams, dt_s: float) -> list[tu.Road]:
    """The roads, built once per worker process."""
    return tu.roads(spec.settings, road, dt_s)


def evaluate_task(task: EvalTask) -> np.ndarray:
    """:func:`ride_sim.tuning.evaluate` of one chunk (runs on a worker)."""
    return tu.evaluate(task.base, task.factors, task.spec, task.car,
                       _roads(task.spec, task.road, task.dt_s), task.dt_s)


@dataclass
class TuneRun:
    """Every design evaluated: unit-cube point, factors, round (−1 the baseline, 0 the
    space-filling design, r the r-th refinement) and :data:`ride_sim.tuning.EVAL_COLUMNS`."""

    spec: tu.TuneSpec
    unit: np.ndarray
    factors: np.ndarray
    rounds: np.ndarray
    values: np.ndarray
    engine: str = ""
    wall_s: float = 0.0
    round_s: list[float] = field(default_factory=list)

    @property
    def objectives(self) -> np.ndarray:
        return self.values[:, :len(tu.OBJECTIVES)]

    @property
    def feasible(self) -> np.ndarray:
        return self.values[:, tu.EVAL_COLUMNS.index("feasible")] > 0.5

    def front(self) -> np.ndarray:
        """Mask of the feasible Pareto front (the baseline competes too)."""
        return tu.pareto_mask(self.objectives, self.feasible)


def _run_round(engine: Engine, base: ModelConfig, factors: np.ndarray, spec: tu.TuneSpec,
               car: QuarterCarParams, road: RoadParams, dt_s: float, say: Say,
               label: str) -> np.ndarray:
    chunk = spec.settings.chunk
    starts = list(range(0, factors.shape[0], chunk))
    out = np.empty((factors.shape[0], len(tu.EVAL_COLUMNS)))
    tasks = ((i, EvalTask(base, factors[i:i + chunk], spec, car, road, dt_s))
             for i in starts)
    t0 = time.perf_counter()
    designs = 0
    for done, outcome in enumerate(engine.map_unordered(evaluate_task, tasks), start=1):
        if outcome.error is not None:
            raise outcome.error
        i = outcome.key
        out[i:i + chunk] = outcome.value
        designs += outcome.value.shape[0]
        elapsed = time.perf_counter() - t0
        say(f"{label} {bar(done, len(starts))} {done}/{len(starts)} tasks, {designs} "
            f"of {factors.shape[0]} designs"
            + (f", about {elapsed / done * (len(starts) - done):.0f} s to go"
               if done < len(starts) else f" in {elapsed:.1f} s"))
    return out


def run_tune(base: ModelConfig, spec: tu.TuneSpec, car: QuarterCarParams, road: RoadParams,
             dt_s: float, engine: Engine, say: Say = print) -> TuneRun:
    """The search (module docstring)."""
    started = time.perf_counter()
    s = spec.settings
    p = len(spec.variables)
    rng = np.random.default_rng(s.seed)
    unit = np.vstack([np.full((1, p), np.nan), tu.sobol(s.designs, p, s.seed)])
    factors = tu.factors_of(np.nan_to_num(unit, nan=0.0), spec)
    factors[0] = 1.0  # the baseline: the base damper itself
    say(f"tuning on {engine.description}: {tu.describe(s)}; {p} variables")
    t0 = time.perf_counter()
    values = _run_round(engine, base, factors, spec, car, road, dt_s, say,
                        f"designs (baseline + {s.designs})")
    rounds = np.r_[-1, np.zeros(s.designs, int)]
    run = TuneRun(spec, unit, factors, rounds, values, engine.description)
    run.round_s.append(time.perf_counter() - t0)
    for r in range(1, s.refine_rounds + 1):
        front = run.front()
        front[0] = False  # the baseline has no point in the cube to move from
        if not front.any():
            say("refinement skipped: no feasible design on the front besides the baseline")
            break
        t0 = time.perf_counter()
        new_unit = tu.refine(run.unit[front], s.refine_designs,
                             s.refine_step / 2 ** (r - 1), rng)
        new_factors = tu.factors_of(new_unit, spec)
        new_values = _run_round(engine, base, new_factors, spec, car, road, dt_s, say,
                                f"refinement {r}/{s.refine_rounds}")
        run.unit = np.vstack([run.unit, new_unit])
        run.factors = np.vstack([run.factors, new_factors])
        run.rounds = np.r_[run.rounds, np.full(s.refine_designs, r)]
        run.values = np.vstack([run.values, new_values])
        run.round_s.append(time.perf_counter() - t0)
    run.wall_s = time.perf_counter() - started
    return run
