"""Run a fleet: every damper's work as one task on the engine, results written as they come
(docs/fleet.md).

Output folder ``OUT``:

* ``OUT/<id>/``: the damper's files, as the single commands write them
  (``identified.yaml``, ``identified.json``, ``validation.json``, ``diagnosis.json``),
  then ``result.json``, its table row, written last and atomically: a damper is finished
  when it exists.  A bug in a damper's task also leaves ``traceback.txt``.
* ``OUT/results.csv``, ``OUT/results.parquet``: one row per damper (:mod:`.table`), with
  the outlier flags (:mod:`.outliers`);
* ``OUT/summary.md`` and its plots (:mod:`.summary`).

**Resume.** A run on an ``OUT`` that already has results keeps every damper with a
``result.json`` (also those in error, unless ``retry_errors``) and runs the others only.

**Nothing stops the fleet.** A damper whose folder lacks a role, whose files are bad or
whose data sheet is bad is one row with ``status: error`` and the one-line reason, found
here before any worker is used; a user error in its work (the model cannot simulate its
stroke, ...) likewise; a bug, as ``bug: <type>: <message>``; a task whose workers kept
dying, as ``worker lost``.
"""

from __future__ import annotations

import json
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from damper_emulator.errors import UserError, one_line
from damper_emulator.outputs import Outputs, write_text
from damper_hil.engine import Engine
from damper_hil.fleet import outliers, table
from damper_hil.fleet.inputs import DamperInputs, find_dampers
from damper_hil.fleet.task import ERROR, DamperJob, DamperResult, error_row, run_damper

#: a damper's finished marker and row
RESULT_FILE = "result.json"
#: the fleet's tables in ``OUT``
TABLES = ("results.csv", "results.parquet")
#: width of the progress bar [characters]
BAR_WIDTH = 24

Say = Callable[[str], None]


@dataclass
class FleetRun:
    """What :func:`run_fleet` did."""

    rows: list[dict[str, Any]]
    flags: dict[str, list[outliers.Flag]]
    #: dampers found finished in ``OUT`` and not run again
    resumed: list[str] = field(default_factory=list)
    wall_s: float = 0.0
    engine: str = ""


def _read_row(folder: Path) -> dict[str, Any] | None:
    """The row of a finished damper, or ``None`` (not finished, or unreadable)."""
    try:
        row = json.loads((folder / RESULT_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return row if isinstance(row, dict) and "status" in row else None


def _save(out: Path, damper_id: str, result: DamperResult) -> dict[str, Any]:
    folder = out / damper_id
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in result.files.items():
        write_text(folder / name, text)
    write_text(folder / RESULT_FILE, json.dumps(result.row, indent=2) + "\n")
    return result.row


def load_job(d: DamperInputs, diagnose: bool, effects: Sequence[str] | None) -> DamperJob:
    """Read one damper's files (through the column map of a ``columns.yaml`` in its
    folder, where there is one) and data sheet (a :class:`UserError` names the bad one)."""
    from damper_emulator.dyno.measured_bag import read_measured
    from damper_emulator.params import DEFAULT_PARAMS_FILE, load_config

    problem = d.problem()
    if problem:
        raise UserError(problem)
    names = [p.name for p in (*d.quasi_static, *d.chirp, *d.validate)]
    if len({n.lower() for n in names}) != len(names):
        raise UserError(f"{d.folder}: two files share a name")
    base = load_config(d.base)
    read = [tuple(read_measured(p) for p in paths)
            for paths in (d.quasi_static, d.chirp, d.validate)]
    return DamperJob(d.id, *read, base=base,
                     base_file=str(d.base if d.base is not None else DEFAULT_PARAMS_FILE),
                     diagnose=diagnose, effects=tuple(effects) if effects else None)


def bar(done: int, total: int) -> str:
    """``[#####.....]`` for ``done`` of ``total``."""
    filled = round(BAR_WIDTH * done / total) if total else BAR_WIDTH
    return "[" + "#" * filled + "." * (BAR_WIDTH - filled) + "]"


def run_fleet(data_dir: Path, out: Path, engine: Engine, diagnose: bool = False,
              effects: Sequence[str] | None = None, retry_errors: bool = False,
              say: Say = print, outputs: Outputs | None = None) -> FleetRun:
    """Identify, validate (and diagnose) every damper of ``data_dir`` into ``out``; module
    docstring.  Returns the rows (every damper, in folder order) and the flags.

    The tables are registered in ``outputs`` before any damper runs (which checks that
    ``out`` can be written) and written into it at the end; the caller commits it, with
    whatever else belongs to the run (the summary).  Without ``outputs`` the tables are
    committed here.
    """
    if outputs is None:
        with Outputs() as own:
            return _run_fleet(data_dir, out, engine, diagnose, effects, retry_errors, say,
                              own)
    return _run_fleet(data_dir, out, engine, diagnose, effects, retry_errors, say, outputs)


def _run_fleet(data_dir: Path, out: Path, engine: Engine, diagnose: bool,
               effects: Sequence[str] | None, retry_errors: bool, say: Say,
               outputs: Outputs) -> FleetRun:
    started = time.perf_counter()
    dampers = find_dampers(data_dir)
    tables = {name: outputs.file(out / name) for name in TABLES}
    rows: dict[str, dict[str, Any]] = {}
    resumed = []
    for d in dampers:
        row = _read_row(out / d.id)
        if row is not None and not (retry_errors and row.get("status") == ERROR):
            rows[d.id] = row
            resumed.append(d.id)
    todo = [d for d in dampers if d.id not in rows]
    total = len(dampers)
    if resumed:
        say(f"resuming {out}: {len(resumed)} of {total} dampers already finished, "
            f"{len(todo)} to run")
    say(f"fleet of {total} dampers on {engine.description}")
    run_started = time.perf_counter()
    ran = 0

    def report(damper_id: str, row: dict[str, Any]) -> None:
        nonlocal ran
        ran += 1
        rows[damper_id] = row
        done = len(rows)
        errors = sum(r.get("status") == ERROR for r in rows.values())
        elapsed = time.perf_counter() - run_started
        eta = elapsed / ran * (total - done)
        what = (f"{row['status']} in {row['wall_s']:.1f} s" if row.get("wall_s") is not None
                else row["status"])
        if row.get("status") == ERROR:
            what += f": {row.get('reason', '')}"
        say(f"{bar(done, total)} {done}/{total} done, {total - done} left"
            f"{f', {errors} in error' if errors else ''}"
            f"{f', about {eta:.0f} s to go' if total > done else ''} | {damper_id} {what}")

    def jobs() -> Iterator[tuple[str, DamperJob]]:
        for d in todo:
            try:
                job = load_job(d, diagnose, effects)
            except UserError as exc:
                report(d.id, _save(out, d.id, DamperResult(error_row(d.id, one_line(exc)))))
                continue
            yield d.id, job

    for outcome in engine.map_unordered(run_damper, jobs()):
        if outcome.error is None:
            result = outcome.value
        else:
            result = DamperResult(error_row(outcome.key, _task_failure(outcome.error)))
            if _is_bug(outcome.error):
                result.files["traceback.txt"] = "".join(traceback.format_exception(
                    outcome.error))
        report(outcome.key, _save(out, outcome.key, result))

    ordered = [rows[d.id] for d in dampers]
    flags = outliers.flag_fleet(ordered)
    for r in ordered:
        r["flags"] = ";".join(f.rule.name for f in flags.get(r["id"], []))
    table.write_csv(ordered, tables["results.csv"])
    table.write_parquet(ordered, tables["results.parquet"])
    return FleetRun(ordered, flags, resumed, time.perf_counter() - started,
                    engine.description)


def _is_bug(exc: BaseException) -> bool:
    return type(exc).__name__ != "KilledWorker"


def _task_failure(exc: BaseException) -> str:
    """The one-line reason of a task that raised (a bug, or its workers kept dying)."""
    if not _is_bug(exc):
        return ("worker lost: the task's worker died every time it ran "
                f"({one_line(exc)}); see the Dask workers' logs")
    return f"bug: {one_line(exc, with_type=True)} (traceback.txt; please report it)"
