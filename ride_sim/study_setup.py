"""What a ride study runs on: its settings (car, roads, time step, the N of the N-speed
test), the synthesised band at a speed and the damper representation of each column
(:data:`~ride_sim.study_paper.ALL_REPRESENTATIONS`), built once per process."""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from typing import Any

from damper_emulator.dyno.protocols import FourteenSpeed
from damper_emulator.errors import UserError
from ride_sim.dampers import TablePlugin, make_damper
from ride_sim.params import QuarterCarParams, RideConfig, RoadParams
from ride_sim.study_paper import ALL_REPRESENTATIONS

# --------------------------------------------------------------------------------------
# dampers


@functools.cache
def default_model():
    """The sport damper (``config/sport.yaml``), built once per process."""
    from damper_emulator.model.compressible import DamperModel

    return DamperModel()


@functools.lru_cache(maxsize=16)
def fourteen_speed_table(model, points: int = FourteenSpeed.points):
    """The N-speed table of ``model`` (a ``DamperModel``), built once per process and
    model (the N-speed test is simulated on the hysteretic model)."""
    from damper_emulator.model.representations import fourteen_speed_damper

    return fourteen_speed_damper(model, points=points)


def make_representation(kind: str, car: QuarterCarParams, model=None,
                        points: int = FourteenSpeed.points, table=None):
    """A damper plug-in for one of :data:`ALL_REPRESENTATIONS` (``table``: a prebuilt
    14-speed :class:`~damper_emulator.model.representations.TableDamper`)."""
    model = default_model() if model is None else model
    if kind == "14speed":
        table = fourteen_speed_table(model, points) if table is None else table
        return TablePlugin(table, name=f"{points}-speed")
    if kind not in ALL_REPRESENTATIONS:
        raise UserError(f"representation {kind!r} must be one of "
                         f"{', '.join(ALL_REPRESENTATIONS)}")
    return make_damper(kind, model, car=car)


# --------------------------------------------------------------------------------------
# settings


@dataclass(frozen=True)
class StudySettings:
    """What a study runs on: the car, the roads, the time step and the N of the N-speed
    test (from a :class:`~ride_sim.params.RideConfig` and the command-line overrides)."""

    car: QuarterCarParams
    road: RoadParams
    dt_s: float = 1e-3
    points: int = FourteenSpeed.points
    source: str = "<memory>"

    @classmethod
    def from_config(cls, cfg: RideConfig, **road_overrides: Any) -> StudySettings:
        """Settings of ``cfg`` with some ``road`` fields replaced (``None`` = keep)."""
        changes = {k: v for k, v in road_overrides.items() if v is not None}
        road = dataclasses.replace(cfg.road, **changes)
        check_road(road)
        return cls(cfg.quarter_car, road, cfg.simulation.step_s,
                   cfg.simulation.fourteen_speed_points, cfg.source)

    def as_dict(self) -> dict[str, Any]:
        return {"config": self.source, "dt_s": self.dt_s, "fourteen_speed_points": self.points,
                "road": {k: (list(v) if isinstance(v, tuple) else v)
                         for k, v in dataclasses.asdict(self.road).items()},
                "quarter_car": dataclasses.asdict(self.car)}


def check_road(road: RoadParams) -> None:
    """Raise :class:`~damper_emulator.errors.UserError` (one line) for road settings a
    study cannot run."""
    lo, hi = road.band_cycles_per_m
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
        raise UserError(f"band [{lo:g}, {hi:g}] cycles/m must satisfy 0 < n_min < n_max")
    for name in ("speed_m_s", "length_m", "pothole_speed_m_s"):
        value = getattr(road, name)
        if not (math.isfinite(value) and value > 0):
            raise UserError(f"{name.replace('_m_s', '').replace('_m', '')} must be a "
                             f"positive number, got {value!r}")
    if not all(math.isfinite(v) and v > 0 for v in road.sweep_speeds_m_s):
        raise UserError(f"sweep speeds must be positive, got {road.sweep_speeds_m_s!r}")
    if isinstance(road.seeds, bool) or not isinstance(road.seeds, int) or road.seeds < 1:
        raise UserError(f"seeds must be a positive integer, got {road.seeds!r}")


def band_at_speed(road: RoadParams, speed_m_s: float) -> tuple[float, float]:
    """The synthesised band [cycles/m] at ``speed_m_s``: ``band_cycles_per_m`` itself
    (``band_scaling = "spatial"``), or the same band in Hz as at ``road.speed_m_s``
    (``"temporal"``: ``n · road.speed_m_s / speed_m_s``)."""
    lo, hi = road.band_cycles_per_m
    if road.band_scaling == "temporal":
        scale = road.speed_m_s / speed_m_s
        return lo * scale, hi * scale
    return lo, hi
