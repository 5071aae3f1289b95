"""What a damper dynamometer can produce: the bounds every measured sample lies within.

Measured data (a CSV, a bag, a recording from a dyno over CAN) whose samples lie outside
these bounds did not come from a damper on a dyno: a wrong unit, a wrong scale, a corrupted
file or a sensor fault.  :func:`damper_emulator.dyno.measured.check_measured` refuses such
data with one line naming the row.  The bounds are generous on purpose: a refusal must
never be a real test.

``MeasuredLimits`` is the schema (docs/parameters.md "Measured-data limits"); its defaults
are the project's limits.
"""

from __future__ import annotations

from dataclasses import dataclass

from damper_emulator.schema import rule


@dataclass(frozen=True)
class MeasuredLimits:
    """The bounds no sample measured on a damper dyno exceeds.

    The force bound is that of the largest damper dynos (heavy-vehicle and rail dampers);
    the stroke and velocity bounds are well beyond any damper's travel and any dyno's
    actuator; the sample intervals span a data logger's 2 Hz to a fast DAQ's 1 MHz.
    """

    max_abs_force_n: float = rule(
        "positive", "largest |force| a damper dyno measures [N] (larger: another unit or "
                    "scale, or a bad sample)", 100e3)
    max_abs_displacement_m: float = rule(
        "positive", "largest |displacement| from the static position [m] (larger: "
                    "millimetres, or a bad sample)", 1.0)
    max_abs_velocity_m_s: float = rule(
        "positive", "largest |velocity| [m/s], of the velocity column and of the "
                    "displacement between two samples (larger: mm/s, or a jump)", 20.0)
    min_temperature_c: float = rule(
        ("closed", -273.15, 0.0), "lowest damper temperature [°C] (lower: a sensor "
                                  "fault)", -60.0)
    max_temperature_c: float = rule(
        "positive", "highest damper temperature [°C] (higher: kelvin, or a sensor fault)",
        250.0)
    min_sample_interval_s: float = rule(
        "positive", "shortest interval between two samples [s] (a 1 MHz DAQ)", 1e-6)
    max_median_interval_s: float = rule(
        "positive", "longest median interval between samples [s] (longer: time in "
                    "milliseconds)", 0.5)
    max_gap_s: float = rule(
        "positive", "longest single interval between two samples [s] (longer: two tests "
                    "in one file, or a bad time stamp)", 60.0)
    max_duration_s: float = rule(
        "positive", "longest test [s] (longer: time in milliseconds, or a bad time "
                    "stamp)", 86_400.0)
    lone_sample_ratio: float = rule(
        "positive", "a sample beyond every other sample of its column by more than this "
                    "times their range is a lone spike [-]", 1.0)
    lone_sample_floor: float = rule(
        ("range", 0.0, 1.0), "...and by more than this fraction of the column's bound "
                             "(so that noise on a flat signal is not a spike) [-]", 0.01)


#: The project's limits.
LIMITS = MeasuredLimits()
