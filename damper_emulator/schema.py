"""The parameter schema: one declaration per parameter, and what is made from it.

A parameter group is a frozen dataclass whose fields are made by :func:`rule` (or
:func:`positive`, :func:`required`): each field's metadata holds its rule
(``positive``, ``("range", lo, hi)``, ``("choices", names)``, ...), its description with
the unit in brackets and whether a running node accepts a change.  From that one
declaration come the checks (:func:`check_value`), the groups built from a params file
(:func:`build_group`, :func:`node_parameters`, :func:`read_yaml`), the ROS parameter
descriptors and the parameter reference (:class:`FieldSpec`, :func:`field_specs`).  Every
broken rule raises :class:`ParameterError`, one line naming the file, the key and the rule.
"""

from __future__ import annotations

import dataclasses
import math
import re
import reprlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import yaml

from damper_emulator.errors import UserError, one_line

if TYPE_CHECKING:  # pragma: no cover
    from _typeshed import DataclassInstance

#: a parameter group (a dataclass of :func:`rule` fields)
_G = TypeVar("_G", bound="DataclassInstance")

#: Default parameter file: the paper's 'sport' damper.
class ParameterError(UserError):
    """A parameter file or value is invalid; the message is one line."""


class _FloatLoader(yaml.SafeLoader):
    """YAML loader that also reads ``1e14`` / ``2.5e-6`` as floats (as ROS 2 does).

    PyYAML follows YAML 1.1, where a float needs a dot and a signed exponent.
    """


_FLOAT_RE = re.compile(
    r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
    |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""",
    re.X,
)
_FloatLoader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_RE, list("-+0123456789."))


def read_yaml(path: str | Path) -> Any:
    """Read a YAML file with ROS 2-compatible float parsing; one-line errors."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ParameterError(f"{path}: cannot read parameter file: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise ParameterError(f"{path}: not a text parameter file (byte {exc.start} is not "
                             f"{exc.encoding})") from None
    try:
        return yaml.load(text, Loader=_FloatLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ParameterError(f"{path}:{where} invalid YAML: {problem}") from None
    except RecursionError:
        raise ParameterError(f"{path}: invalid YAML: nested too deeply") from None
    except Exception as exc:  # noqa: BLE001 - the constructors' errors, listed below
        # what PyYAML's constructors let through: the errors of int(), datetime() and
        # their look-ups on an integer of more than 4300 digits (Python's int() limit), an
        # impossible date or time zone, or a scalar with a tag it does not fit (!!bool x,
        # !!timestamp x)
        raise ParameterError(f"{path}: invalid YAML: {one_line(exc, with_type=True)}") \
            from None


# --------------------------------------------------------------------------------------
# Fields: a value's rule, description, unit and whether it may change at run time


def positive(doc: str) -> Any:
    return field(metadata={"rule": "positive", "doc": doc})


def required(kind: Any, doc: str) -> Any:
    """A field of rule ``kind`` with no default, like :func:`positive`'s.  (mypy's dataclass
    plugin knows only ``field()``: it takes any other call, :func:`positive`'s too, for a
    default, and refuses a plain ``field()`` without one after them.)"""
    return field(metadata={"rule": kind, "doc": doc})


def rule(kind: Any, doc: str, default: Any = dataclasses.MISSING, *,
         runtime: bool = False) -> Any:
    """A dataclass field checked by :func:`check_value`: ``rule`` is ``"positive"``,
    ``"non-negative"``, ``"finite"`` (any number), ``"bool"``, ``"text"``,
    ``("range", lo, hi)`` (lo exclusive),
    ``("closed", lo, hi)``,
    ``("int_range", lo, hi)``, ``("choices", names)``, ``"band"`` or ``"positive_list"``;
    ``doc`` says what the value is, with its unit in brackets (``[m]``; ``[-]``
    dimensionless); ``runtime``: a running node accepts a change of it (otherwise it needs
    a restart)."""
    return field(default=default, metadata={"rule": kind, "doc": doc, "runtime": runtime})


# --------------------------------------------------------------------------------------
# The schema, read back: what the ROS descriptors and the parameter reference are made of


@dataclass(frozen=True)
class FieldSpec:
    """One parameter as its group's schema declares it (:func:`field_specs`).

    ``type`` is the ROS 2 parameter type's name (``double``, ``integer``, ``bool``,
    ``string``, ``double_array``); ``lo``/``hi`` bound a number (``lo_open``: ``lo``
    excluded; ``None``: unbounded); ``choices`` the allowed strings; ``default`` ``None``
    when the group has none (the value comes from the params file)."""

    key: str
    type: str
    unit: str
    description: str
    constraint: str
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    choices: tuple[str, ...] = ()
    default: Any = None
    runtime: bool = False


#: the unit in a description: the first ``[...]`` after a space (not an index, ``name[0]``)
_UNIT = re.compile(r"(?:^|\s)\[([^\[\]]*)\]")


def field_spec(f: dataclasses.Field[Any], key: str) -> FieldSpec:
    """The :class:`FieldSpec` of one :func:`rule` field, named ``key``."""
    kind_rule, doc = f.metadata["rule"], f.metadata["doc"]
    kind = kind_rule[0] if isinstance(kind_rule, tuple) else kind_rule
    unit_match = _UNIT.search(doc)
    unit = unit_match.group(1) if unit_match and kind not in ("bool", "text", "choices") \
        else ""
    default = None if f.default is dataclasses.MISSING else f.default
    if isinstance(default, tuple):
        default = list(default)
    common = {"key": key, "unit": unit, "description": doc, "default": default,
              "runtime": bool(f.metadata.get("runtime", False))}
    if kind == "bool":
        return FieldSpec(type="bool", constraint="true or false", **common)
    if kind == "text":
        return FieldSpec(type="string", constraint="text", **common)
    if kind == "choices":
        return FieldSpec(type="string", constraint="one of " + ", ".join(kind_rule[1]),
                         choices=tuple(kind_rule[1]), **common)
    if kind in ("band", "positive_list"):
        what = "two increasing positive numbers" if kind == "band" else "positive numbers"
        return FieldSpec(type="double_array", constraint=what, lo=0.0, lo_open=True, **common)
    if kind == "int_range":
        return FieldSpec(type="integer", constraint=f"integer in [{kind_rule[1]}, "
                         f"{kind_rule[2]}]", lo=kind_rule[1], hi=kind_rule[2], **common)
    if kind == "positive":
        return FieldSpec(type="double", constraint="> 0", lo=0.0, lo_open=True, **common)
    if kind == "non-negative":
        return FieldSpec(type="double", constraint=">= 0", lo=0.0, **common)
    if kind == "finite":
        return FieldSpec(type="double", constraint="finite", **common)
    if kind == "range":
        return FieldSpec(type="double", constraint=f"in ({kind_rule[1]:g}, {kind_rule[2]:g}]",
                         lo=kind_rule[1], hi=kind_rule[2], lo_open=True, **common)
    if kind == "closed":
        return FieldSpec(type="double", constraint=f"in [{kind_rule[1]:g}, {kind_rule[2]:g}]",
                         lo=kind_rule[1], hi=kind_rule[2], **common)
    raise AssertionError(f"{key}: rule {kind_rule!r} has no spec")  # a bug in the schema


# --------------------------------------------------------------------------------------
# Building a group from a params file


def node_parameters(doc: Any, where: str, group: str = "damper") -> Mapping[str, Any]:
    """The ``ros__parameters`` mapping of a ROS 2 params file that holds ``group``, or the
    bare mapping when ``group`` is at its top level.

    Raises
    ------
    ParameterError
        One line: not a mapping, or no node's parameters hold ``group``.
    """
    if not isinstance(doc, Mapping):
        raise ParameterError(f"{where}: expected a mapping at the top level")
    if group in doc:
        return doc
    for body in doc.values():
        if isinstance(body, Mapping) and isinstance(body.get("ros__parameters"), Mapping):
            params: Mapping[str, Any] = body["ros__parameters"]
            if group in params:
                return params
    raise ParameterError(f"{where}: no '{group}' parameters found (expected "
                         f"'<node>: ros__parameters: {group}: ...' or '{group}: ...')")


def build_group(cls: type[_G], data: Any, prefix: str, where: str,
                convert: Callable[[Any, dataclasses.Field[Any], str, str], Any]) -> _G:
    """One parameter group: the dataclass ``cls`` from the mapping ``data``.

    Unknown keys and missing keys without a default are refused (one-line
    :class:`ParameterError` naming ``prefix.key`` and the file ``where``); every value goes
    through ``convert(raw, field, "prefix.key", where)``, which checks it and returns the
    value to store.
    """
    if not isinstance(data, Mapping):
        raise ParameterError(f"{where}: {prefix} must be a mapping")
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - names, key=str)  # (YAML keys may mix types)
    if unknown:
        raise ParameterError(f"{where}: unknown parameter {prefix}.{unknown[0]}")
    values: dict[str, Any] = {}
    for f in fields(cls):
        key = f"{prefix}.{f.name}"
        if f.name not in data:
            if f.default is dataclasses.MISSING:
                raise ParameterError(f"{where}: missing parameter {key} ({f.metadata['doc']})")
            continue
        values[f.name] = convert(data[f.name], f, key, where)
    return cls(**values)


# --------------------------------------------------------------------------------------
# Checking a value against its field's rule (the one checker of every group)

#: A value as an error message shows it: its repr, cut short (a few elements of a few
#: levels, 60 characters of a scalar).  A YAML alias bomb, a few lines of anchors that
#: expand to millions of elements, must not be expanded into the message.
_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxstring, _REPR.maxother, _REPR.maxlong = 3, 60, 60, 60
_shown = _REPR.repr


def check_value(value: Any, f: dataclasses.Field[Any], key: str, where: str) -> Any:
    """Coerce and check one value; raise a one-line :class:`ParameterError`."""
    rule, doc = f.metadata["rule"], f.metadata["doc"]
    kind = rule[0] if isinstance(rule, tuple) else rule
    if kind == "bool":
        if not isinstance(value, bool):
            raise ParameterError(f"{where}: {key} must be true or false, got {_shown(value)}")
        return value
    if kind == "text":
        if not isinstance(value, str):
            raise ParameterError(f"{where}: {key} must be a string, got {_shown(value)}")
        return value
    if kind == "choices":
        if not isinstance(value, str):
            raise ParameterError(f"{where}: {key} must be a string, got {_shown(value)}")
        if value not in rule[1]:
            raise ParameterError(f"{where}: {key} = {_shown(value)} must be one of "
                                 f"{', '.join(rule[1])}")
        return value
    if kind in ("band", "positive_list"):
        return check_list(value, kind, key, where, doc)
    if kind == "int_range":
        if isinstance(value, bool) or not isinstance(value, int):
            raise ParameterError(f"{where}: {key} must be an integer, got {_shown(value)}")
        if not rule[1] <= value <= rule[2]:
            raise ParameterError(f"{where}: {key} = {value} must lie in "
                                 f"[{rule[1]}, {rule[2]}] ({doc})")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f"{where}: {key} must be a number, got {_shown(value)}")
    try:
        value = float(value)
    except OverflowError:  # an integer beyond the float range
        raise ParameterError(f"{where}: {key} = {_shown(value)} is too large "
                             f"({doc})") from None
    if not math.isfinite(value):
        raise ParameterError(f"{where}: {key} = {value} must be finite ({doc})")
    if kind == "positive" and not value > 0:
        raise ParameterError(f"{where}: {key} = {value:g} must be positive ({doc})")
    if kind == "non-negative" and not value >= 0:
        raise ParameterError(f"{where}: {key} = {value:g} must not be negative ({doc})")
    if kind == "range" and not rule[1] < value <= rule[2]:
        raise ParameterError(f"{where}: {key} = {value:g} must lie in "
                             f"({rule[1]:g}, {rule[2]:g}] ({doc})")
    if kind == "closed" and not rule[1] <= value <= rule[2]:
        raise ParameterError(f"{where}: {key} = {value:g} must lie in "
                             f"[{rule[1]:g}, {rule[2]:g}] ({doc})")
    return value


def check_list(value: Any, kind: str, key: str, where: str, doc: str) -> tuple[float, ...]:
    """A list of positive numbers; for ``band`` exactly two, increasing."""
    if isinstance(value, (str, bytes, Mapping)) or not hasattr(value, "__iter__"):
        raise ParameterError(f"{where}: {key} must be a list of numbers, got {_shown(value)}")
    items = list(value)
    if kind == "band" and len(items) != 2:
        raise ParameterError(f"{where}: {key} must be two numbers [low, high] ({doc}), "
                             f"got {_shown(value)}")
    if not items:
        raise ParameterError(f"{where}: {key} must not be empty ({doc})")
    out = []
    for item in items:
        if isinstance(item, bool) or not isinstance(item, (int, float)):
            raise ParameterError(f"{where}: {key} must hold numbers, got {_shown(item)}")
        try:
            x = float(item)
        except OverflowError:  # an integer beyond the float range
            raise ParameterError(f"{where}: {key} holds {_shown(item)}, too large "
                                 f"({doc})") from None
        if not (math.isfinite(x) and x > 0):
            raise ParameterError(f"{where}: {key} holds {x:g}: every value must be positive "
                                 f"and finite ({doc})")
        out.append(x)
    if kind == "band" and not out[0] < out[1]:
        raise ParameterError(f"{where}: {key} = [{out[0]:g}, {out[1]:g}] must be increasing "
                             f"({doc})")
    return tuple(out)
