"""What the subcommands of ``damper-hil`` share: the program name, argument types,
the help formatter and small output helpers."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from damper_emulator.errors import UserError
from damper_emulator.schema import ParameterError, check_value, field_spec

PROG = "damper-hil"


class CliError(UserError):
    """A user error detected by the command line itself (one-line message)."""


# --------------------------------------------------------------------------------------


def number_type(kind: str, test: Callable[[float], bool], cast: Callable = float):
    def parse(text: str):
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {kind}, got {text!r}") from None
        if not (math.isfinite(value) and test(value)):
            raise argparse.ArgumentTypeError(f"expected {kind}, got {text!r}")
        return value
    return parse


def schema_type(f: dataclasses.Field, option: str) -> Callable[[str], Any]:
    """The argparse ``type`` of an option that sets the schema field ``f`` (a number;
    :func:`damper_emulator.schema.rule`): the text as the field's type, checked by the
    field's rule; a broken rule is argparse's usage error naming ``option``."""
    spec = field_spec(f, option)
    cast = int if spec.type == "integer" else float
    what = f"an {spec.constraint}" if spec.type == "integer" else f"a number {spec.constraint}"

    def parse(text: str) -> Any:
        try:
            return check_value(cast(text), f, option, "")
        except (ValueError, ParameterError):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    return parse


positive_float = number_type("a positive number", lambda v: v > 0)
non_negative_float = number_type("a number >= 0", lambda v: v >= 0)
positive_int = number_type("a positive integer", lambda v: v >= 1, int)
non_negative_int = number_type("an integer >= 0", lambda v: v >= 0, int)


class Formatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions and epilogs keep their line breaks; option help is wrapped."""


def say_wrote(path: Path) -> None:
    print(f"wrote {path}", file=sys.stderr, flush=True)


def check_unique_names(paths: Sequence[Path]) -> None:
    """Results are keyed by base name: refuse two files with the same one, before any
    work."""
    seen: dict[str, Path] = {}
    for p in paths:
        if p.name in seen:
            raise CliError(f"two data files have the base name {p.name!r} ({seen[p.name]} "
                           f"and {p}): results are keyed by base name")
        seen[p.name] = p


def say(message: str) -> None:
    """A progress or result line on stderr."""
    print(message, file=sys.stderr, flush=True)


def json_text(doc: dict[str, Any]) -> str:
    """The project's JSON layout (two-space indent, a final newline)."""
    return json.dumps(doc, indent=2) + "\n"


def write_json(path: Path, doc: dict[str, Any]) -> None:
    """``doc`` to ``path`` at once (atomically: a temporary sibling renamed into place)."""
    from damper_emulator.outputs import write_text

    write_text(path, json_text(doc))
    say_wrote(path)


def add_engine_options(parser: argparse.ArgumentParser) -> None:
    """``--scheduler ADDRESS | --workers N``: where the Dask tasks run
    (:func:`damper_hil.engine.open_engine`)."""
    engine = parser.add_mutually_exclusive_group()
    engine.add_argument("--scheduler", metavar="ADDRESS", default=None,
                        help="a running Dask scheduler, e.g. tcp://127.0.0.1:8786")
    engine.add_argument("--workers", metavar="N", type=positive_int, default=None,
                        help="local Dask worker processes (default: the CPU count; 1: "
                             "in this process)")


def parse_effects(text: str | None, option: str = "--effects") -> list[str] | None:
    """A comma-separated subset of the diagnosis's candidates (``None``: all)."""
    if text is None:
        return None
    from damper_emulator.params import EXTENSION_TYPES

    effects = [e.strip() for e in text.split(",") if e.strip()]
    unknown = [e for e in effects if e not in EXTENSION_TYPES]
    if unknown or not effects:
        raise CliError(f"{option}: unknown effect {unknown[0] if unknown else '(none)'!r}"
                       f" (one of {', '.join(EXTENSION_TYPES)})")
    return effects


def load_model(params: Path | None):
    from damper_emulator.model.compressible import DamperModel
    from damper_emulator.params import DEFAULT_PARAMS_FILE, load_config

    cfg = load_config(params)
    return DamperModel(cfg), str(params if params is not None else DEFAULT_PARAMS_FILE)


def add_rig_option(parser: argparse.ArgumentParser) -> None:
    """``--rig RIG.yaml``: the measurement chain the data files were recorded through."""
    parser.add_argument("--rig", metavar="RIG.yaml", type=Path, default=None,
                        help="the rig's acquisition data sheet: each channel's analog "
                             "filter (type, order, cut-off), converter and skew "
                             "(docs/diagnose.md, 'The measurement chain'); the model's "
                             "force passes through it before it is compared with the data")


def add_columns_options(parser: argparse.ArgumentParser) -> None:
    """How the data files' columns are read: ``--columns QUANTITY=COLUMN ...`` and the
    rest of a column map (:mod:`damper_emulator.dyno.column_map`)."""
    from damper_emulator.dyno.column_map import SIDECAR, ZEROS

    group = parser.add_argument_group(
        "data columns (a lab's export: names, units, time stamps, signs; default: the "
        f"map of a {SIDECAR} beside the files, else time,displacement,force in SI)")
    group.add_argument("--columns", metavar="QUANTITY=COLUMN", nargs="+", default=None,
                       help="the column of each quantity (time, displacement, force, "
                            "velocity, temperature), e.g. time=Timestamp "
                            "displacement='Displacement (mm)' force='Force (N)'; the "
                            "unit at the end of a name, (mm), [in], _kN, is converted to SI, "
                            "time may be ISO 8601 stamps")
    group.add_argument("--column-map", metavar="MAP.yaml", type=Path, default=None,
                       help=f"the column map as a YAML file (the keys of {SIDECAR}: "
                            "columns, sample_rate_hz, force_sign, displacement_sign, "
                            "displacement_zero)")
    group.add_argument("--sample-rate", metavar="HZ", type=positive_float, default=None,
                       help="no time column: samples at this rate [Hz]")
    group.add_argument("--force-sign", type=int, choices=(1, -1), default=None,
                       help="-1: the file's force is compression-positive (the project's "
                            "is rebound-positive)")
    group.add_argument("--displacement-sign", type=int, choices=(1, -1), default=None,
                       help="-1: the file's displacement is compression-positive (the "
                            "project's is extension-positive)")
    group.add_argument("--displacement-zero", choices=ZEROS, default=None,
                       help="mid-stroke: the stroke's zero halfway between the file's "
                            "extremes (default: file, as recorded)")
    group.add_argument("--velocity-window", metavar="N", type=int, default=None,
                       help="no velocity column: the displacement's cubic Savitzky-Golay "
                            "derivative over N samples (odd), not the plain derivative")


def columns_of(args: argparse.Namespace) -> Any:
    """The column options of :func:`add_columns_options`
    (:class:`~damper_emulator.dyno.column_map.ColumnOptions`; None: none given, each
    file read through its sidecar, or as the project's CSV)."""
    from damper_emulator.dyno.column_map import (
        ColumnMap,
        ColumnOptions,
        load_column_map,
        parse_assignments,
    )

    given = {"sample_rate_hz": args.sample_rate, "force_sign": args.force_sign,
             "displacement_sign": args.displacement_sign,
             "displacement_zero": args.displacement_zero,
             "velocity_window": args.velocity_window}
    if args.columns is None and args.column_map is None and all(
            v is None for v in given.values()):
        return None
    options = ColumnOptions(
        base=load_column_map(args.column_map) if args.column_map is not None else None,
        columns=parse_assignments(args.columns) if args.columns is not None else {},
        settings={k: float(v) if k in FLOAT_KEYS else v for k, v in given.items()
                  if v is not None})
    # a bad map fails here, before any file is read (a sidecar's, when its file is)
    dataclasses.replace(options, base=options.base or ColumnMap()).for_file(".")
    return options


#: the column map's options that are numbers of a float field
FLOAT_KEYS = ("sample_rate_hz", "force_sign", "displacement_sign")


def read_data(paths: Sequence[Path], rig: Path | None, columns: Any = None) -> list[Any]:
    """The measured-data files ``paths`` (each read and checked before any work), read
    through the column options ``columns`` (:func:`columns_of`; None: each file's
    sidecar, or none), with the rig file ``rig``'s chain attached when given."""
    from damper_emulator.dyno.measured_bag import read_measured

    chain = None
    if rig is not None:
        from damper_emulator.acquisition.rig import load_rig

        chain = load_rig(rig)
    from damper_emulator.dyno.column_map import SIDECAR

    for folder in dict.fromkeys(Path(p).parent for p in paths):
        if (folder / SIDECAR).is_file() and (columns is None or columns.base is None):
            say(f"reading the files of {folder} through its {SIDECAR}")
    data = [read_measured(p, None if columns is None else columns.for_file(p))
            for p in paths]
    return [dataclasses.replace(d, acquisition=chain) for d in data] if chain else data


def add_realtime_options(parser: argparse.ArgumentParser, priority: int) -> None:
    """``--priority P`` and ``--cpu N``: the loop thread's SCHED_FIFO priority (when
    permitted) and the CPU it is pinned to (-1: the affinity left alone)."""
    parser.add_argument("--priority", metavar="P", type=int, choices=range(1, 100),
                        default=priority,
                        help=f"SCHED_FIFO priority of the loop thread when permitted "
                             f"(default: {priority})")
    parser.add_argument("--cpu", metavar="N", type=int, default=-1,
                        help="pin the loop thread to CPU N (default: -1, leave the affinity "
                             "alone; with the dyno's loop on another CPU the response "
                             "time's tail shortens)")
