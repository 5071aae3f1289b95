"""The parameter reference, ``docs/parameters.md``, generated from the schema.

Every parameter group is a dataclass whose fields declare their rule, description (with the
unit) and whether a running node accepts a change (:func:`damper_emulator.schema.rule`);
:func:`damper_emulator.params.field_specs` reads that back.  This module writes it as one
table per group, with the value of the project's default params file.

``python -m damper_hil.param_reference`` rewrites the file; ``--check`` exits 1 when it is
out of date (a test runs that).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from damper_emulator.params import field_specs
from damper_emulator.schema import FieldSpec

REPO = Path(__file__).resolve().parents[1]
OUTPUT = REPO / "docs" / "parameters.md"


def _groups() -> list[tuple[str, str, str, type, Callable[[], Any]]]:
    """``(group, params file, who reads it, dataclass, loader of the defaults)``."""
    from can_bridge.settings import BridgeParams, bridge_params_from_mapping
    from damper_emulator.acquisition.rig import DisplacementChannel, ForceChannel, load_rig
    from damper_emulator.managed_settings import ManagedNodeParams
    from damper_emulator.params import DamperParams, NumericsParams, load_config
    from damper_emulator.realtime.settings import EmulatorParams
    from ride_sim.hybrid.params import GROUPS as HYBRID_GROUPS
    from ride_sim.hybrid.params import load_hybrid_config
    from ride_sim.params import (
        QuarterCarParams,
        RideRunParams,
        RoadParams,
        SimulationParams,
        load_ride_config,
    )
    from ride_sim.skyhook import SkyhookParams, load_skyhook

    # each params file read once for all its groups
    model, ride = functools.cache(load_config), functools.cache(load_ride_config)
    hybrid = functools.cache(load_hybrid_config)
    rig = functools.cache(lambda: load_rig(Path(__file__).resolve().parents[1] / "config"
                                           / "rig.yaml"))
    return [
        ("damper", "config/sport.yaml", "every node and subcommand that runs the model",
         DamperParams, lambda: model().damper),
        ("numerics", "config/sport.yaml", "the model's numerical settings", NumericsParams,
         lambda: model().numerics),
        ("emulator", "config/emulator.yaml", "the `damper_emulator` node, `replay`",
         EmulatorParams, EmulatorParams),
        ("", "config/bridge.yaml", "the `can_bridge` node (parameters without a group)",
         BridgeParams, lambda: bridge_params_from_mapping(None)),
        ("", "",
         "the managed nodes `damper_emulator` and `can_bridge` (without a group)",
         ManagedNodeParams, ManagedNodeParams),
        ("quarter_car", "config/quarter_car.yaml", "the ride node and `ride-study`",
         QuarterCarParams, lambda: ride().quarter_car),
        ("simulation", "config/quarter_car.yaml", "the ride node and `ride-study`",
         SimulationParams, lambda: ride().simulation),
        ("road", "config/quarter_car.yaml", "`ride-study` and the ride node", RoadParams,
         lambda: ride().road),
        ("ride", "config/quarter_car.yaml", "the ride node", RideRunParams,
         lambda: ride().ride),
        ("skyhook", "config/skyhook.yaml", "`skyhook`, `ride-study --figure adaptive`",
         SkyhookParams, load_skyhook),
        ("rig.force", "config/rig.yaml",
         "`identify`, `diagnose` and `validate` given `--rig` (the file is an example)",
         ForceChannel, lambda: rig().force),
        ("rig.displacement", "config/rig.yaml",
         "`identify`, `diagnose` and `validate` given `--rig` (the file is an example)",
         DisplacementChannel,
         lambda: rig().displacement),
    ] + [(key, "config/hybrid.yaml", "`hybrid`" if key not in ("actuator", "virtual_rig") else
          "`virtual-rig`", cls, functools.partial(lambda k: getattr(hybrid(), k), key))
         for key, cls in HYBRID_GROUPS.items()]


def _value(obj: Any, key: str) -> Any:
    for part in key.split("."):
        if obj is None:
            return None
        obj = getattr(obj, part)
    return obj


def _fmt(value: Any) -> str:
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    if dataclasses.is_dataclass(value):
        return "(group)"
    return f"`{value}`" if isinstance(value, str) and value else (str(value) or "''")


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def render() -> str:
    """The whole document."""
    lines = [
        "# Parameter reference",
        "",
        "Generated from the parameter schema by `python -m damper_hil.param_reference`;",
        "do not edit by hand (a test checks it is up to date). Each group is a dataclass",
        "whose fields declare their type, unit, rule and description",
        "(`damper_emulator.schema.rule`); the loaders, the checks, the ROS 2 parameter",
        "descriptors and this page all come from it. *Default* is the value in the",
        "project's params file (or the group's own default). *Run time*: a running node",
        "accepts a change with `ros2 param set` (the others need a restart). Units are SI;",
        "`-` is dimensionless.",
        "",
    ]
    for group, path, who, cls, defaults in _groups():
        specs: list[FieldSpec] = field_specs(cls, group)
        obj = defaults()
        heading = group or ("managed nodes" if cls.__name__ == "ManagedNodeParams"
                            else "can_bridge")
        lines += [f"## `{heading}`", "",
                  (f"In `{path}`" if path else "On the node's command line "
                   "(`-p autostart:=false`), in no params file") + f"; read by {who}. "
                  f"{_cell((cls.__doc__ or '').strip().splitlines()[0])}", "",
                  "| parameter | type | unit | rule | default | run time | description |",
                  "|---|---|---|---|---|---|---|"]
        for s in specs:
            key = s.key[len(group) + 1:] if group else s.key
            lines.append(f"| `{s.key}` | {s.type} | {_cell(s.unit) or ' '} | "
                         f"{_cell(s.constraint)} | {_cell(_fmt(_value(obj, key)))} | "
                         f"{'yes' if s.runtime else 'no'} | {_cell(s.description)} |")
        lines.append("")
    lines += _limits_table()
    lines += _protocol_tables()
    lines += _scatter_table()
    lines += _tune_tables()
    return "\n".join(lines)


def _limits_table() -> list[str]:
    """The bounds every measured sample lies within, from their schema."""
    from damper_emulator.dyno.limits import MeasuredLimits

    return _options_table("## Measured-data limits", MeasuredLimits, lambda key: "",
                          intro="Fixed (no params file, no option); checked by every reader "
                          "of measured data (`damper_emulator.dyno.measured.check_measured`:"
                          " CSV files, bags, the dyno's recordings), each refusal naming "
                          "the first bad row.")


def _protocol_tables() -> list[str]:
    """The settings of ``damper-hil dyno``'s protocols, one table per protocol, from their
    schemas (:data:`damper_emulator.dyno.protocols.PROTOCOLS`), with the option that sets
    each."""
    from damper_emulator.dyno.protocols import PROTOCOLS
    from damper_hil.cli.dyno import option_dest

    lines = ["## `damper-hil dyno` protocols", "",
             "Command-line options, not ROS parameters; `diagnose`'s simulated sessions use "
             "the same defaults.", ""]
    for name, cls in PROTOCOLS.items():
        lines += [f"### `--protocol {name}`", "",
                  _cell(" ".join((cls.__doc__ or "").split())), "",
                  "| option | setting | type | unit | rule | default | description |",
                  "|---|---|---|---|---|---|---|"]
        for s in field_specs(cls, ""):
            lines.append(f"| `--{option_dest(s.key).replace('_', '-')}` | `{s.key}` | "
                         f"{s.type} | {_cell(s.unit) or ' '} | {_cell(s.constraint)} | "
                         f"{_cell(_fmt(s.default))} | {_cell(s.description)} |")
        lines.append("")
    return lines


def _scatter_table() -> list[str]:
    """The unit-to-unit scatter of ``damper-hil fleet-example``, from its schema."""
    from damper_hil.cli.fleet_example import scatter_option
    from damper_hil.fleet.scatter import Scatter

    return _options_table("## `damper-hil fleet-example` scatter", Scatter,
                          lambda key: scatter_option(key))


def _tune_tables() -> list[str]:
    """The settings and bounds of ``damper-hil tune``, from their schemas."""
    from damper_hil.cli.tune import OPTIONS, option_of
    from ride_sim.params import TuneBounds, TuneSettings

    lines = _options_table("## `damper-hil tune` settings", TuneSettings,
                           lambda key: (option_of(key) if key in (*OPTIONS, "bypass")
                                        else ""),
                           prefix="tune", intro="In the `tune` group of `--settings` "
                           "(`config/tune.yaml`); an option, where there is one, overrides "
                           "the file.")
    return lines + _options_table("### `tune.bounds`", TuneBounds, lambda key: "",
                                  prefix="tune.bounds")


def _options_table(title: str, cls: type, option: Callable[[str], str], prefix: str = "",
                   intro: str = "") -> list[str]:
    """One table of a schema's settings: key, option, type, unit, rule, default."""
    lines = [title, "", _cell(" ".join((cls.__doc__ or "").split()))
             + (f" {intro}" if intro else ""), "",
             "| setting | option | type | unit | rule | default | description |",
             "|---|---|---|---|---|---|---|"]
    for s in field_specs(cls, prefix):
        key = s.key[len(prefix) + 1:] if prefix else s.key
        opt = option(key)
        lines.append(f"| `{s.key}` | {f'`{opt}`' if opt else '–'} | {s.type} | "
                     f"{_cell(s.unit) or ' '} | {_cell(s.constraint)} | "
                     f"{_cell(_fmt(s.default))} | {_cell(s.description)} |")
    lines.append("")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="write docs/parameters.md from the schema")
    ap.add_argument("--check", action="store_true",
                    help="exit 1 when docs/parameters.md is not what the schema gives")
    args = ap.parse_args(argv)
    text = render()
    if args.check:
        current = OUTPUT.read_text(encoding="utf-8") if OUTPUT.exists() else ""
        if current != text:
            print(f"{OUTPUT} is out of date: run python -m damper_hil.param_reference",
                  file=sys.stderr)
            return 1
        return 0
    OUTPUT.write_text(text, encoding="utf-8")
    print(f"wrote {OUTPUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
