"""ROS parameters from the schema: the descriptors a node declares from its parameter
groups (:mod:`damper_emulator.schema`), the values a params file overrides, and the
flattened keys ROS uses for nested groups."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.exceptions import InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter as RclpyParameter

from damper_emulator.params import field_specs
from damper_emulator.schema import FieldSpec, ParameterError


def flatten(mapping: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"a": {"b": 1}}`` → ``{"a.b": 1}`` (ROS 2 parameter names)."""
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flatten(value, name + "."))
        else:
            out[name] = value
    return out


def unflatten(flat: Mapping[str, Any]) -> dict[str, Any]:
    """Inverse of :func:`flatten`."""
    out: dict[str, Any] = {}
    for name, value in flat.items():
        parts = name.split(".")
        d = out
        for p in parts[:-1]:
            d = d.setdefault(p, {})
        d[parts[-1]] = value
    return out


#: ROS 2 parameter type of each schema type (:attr:`damper_emulator.schema.FieldSpec.type`)
_ROS_TYPES = {"double": ParameterType.PARAMETER_DOUBLE,
              "integer": ParameterType.PARAMETER_INTEGER,
              "bool": ParameterType.PARAMETER_BOOL,
              "string": ParameterType.PARAMETER_STRING,
              "double_array": ParameterType.PARAMETER_DOUBLE_ARRAY}


def parameter_overrides(node: Node) -> Mapping[str, Any]:
    """The values given to ``node`` by ``--params-file`` and ``-p`` (name → rclpy
    ``Parameter``).

    rclpy keeps them in a private attribute and offers no public accessor; they are read
    here, in this one place, for two things rclpy does not do: refuse a parameter of ours
    that no schema declares (rclpy ignores it without a word), and take an integer written
    for a real-valued parameter (``stiffness: 200000``) as that real."""
    return getattr(node, "_parameter_overrides", {})


def schema_specs(schema: Mapping[str, type]) -> dict[str, FieldSpec]:
    """Every parameter of the groups in ``schema`` (group name → its dataclass; ``""``: the
    parameters without a group), by dotted name."""
    return {spec.key: spec for group, cls in schema.items()
            for spec in field_specs(cls, group)}


def parameter_descriptor(spec: FieldSpec) -> ParameterDescriptor:
    """The ROS 2 descriptor of one schema entry: its real type, description (unit in
    brackets), the rule as ``additional_constraints``, the bounds as a
    ``floating_point_range`` / ``integer_range`` (an open bound, ``> 0``, is given as the
    closed one and refused by the rule), and ``read_only`` unless a running node accepts a
    change (:func:`damper_emulator.schema.rule`'s ``runtime``)."""
    descriptor = ParameterDescriptor(type=_ROS_TYPES[spec.type], description=spec.description,
                                     additional_constraints=spec.constraint,
                                     read_only=not spec.runtime)
    if spec.type == "double" and (spec.lo is not None or spec.hi is not None):
        descriptor.floating_point_range = [FloatingPointRange(
            from_value=-math.inf if spec.lo is None else float(spec.lo),
            to_value=math.inf if spec.hi is None else float(spec.hi), step=0.0)]
    elif spec.type == "integer" and spec.lo is not None and spec.hi is not None:
        descriptor.integer_range = [IntegerRange(from_value=int(spec.lo),
                                                 to_value=int(spec.hi), step=1)]
    return descriptor


def _as_schema_type(value: Any, spec: FieldSpec) -> Any:
    """``value`` as the schema's ROS type where that loses nothing: an integer for a real
    (YAML's ``200000``), a tuple or a list of integers for a real array."""
    def number(v: Any) -> bool:
        return isinstance(v, (int, float)) and not isinstance(v, bool)

    if spec.type == "double" and number(value):
        return float(value)
    if spec.type == "double_array" and isinstance(value, (list, tuple)) \
            and all(number(v) for v in value):
        return [float(v) for v in value]
    return plain_value(value)


def _ros_type(value: Any) -> int:
    """The ROS 2 parameter type rclpy gives ``value`` (``PARAMETER_NOT_SET``: none)."""
    try:
        return RclpyParameter.Type.from_parameter_value(value).value
    except TypeError:
        return ParameterType.PARAMETER_NOT_SET


def declare_parameters(node: Node, defaults: Mapping[str, Any],
                       schema: Mapping[str, type]) -> dict[str, Any]:
    """Declare every parameter of ``defaults`` (nested mapping) on ``node`` with its
    schema's descriptor (:func:`parameter_descriptor`), taking the value of a
    ``--params-file`` / ``-p`` override where one is given, and return the nested mapping
    of the values in effect.

    ``schema`` maps each group to its dataclass (``""``: parameters without a group).
    Overrides in those groups that match no known parameter are refused; other groups
    belong to other nodes sharing the file and are ignored.  A value of the wrong type or
    outside the descriptor's range is refused too.  Each refusal is a
    :class:`ParameterError` of one line naming the parameter.
    """
    specs = schema_specs(schema)
    flat = flatten(defaults)
    overrides = parameter_overrides(node)
    where = f"node {node.get_name()} parameters"
    prefixes = tuple(f"{g}." for g in schema if g)

    def ours(name: str) -> bool:
        return name.startswith(prefixes) or ("" in schema and "." not in name)

    # (an override may also have reached ``defaults``: the model extensions a params file
    # names are added to them, misspelt ones included)
    unknown = sorted({n for n in overrides
                      if ours(n) and n not in flat and not node.has_parameter(n)}
                     | {n for n in flat if n not in specs and n in overrides})
    if unknown:
        raise ParameterError(f"node {node.get_name()}: unknown parameter {unknown[0]}")
    values: dict[str, Any] = {}
    for name, default in flat.items():
        spec = specs[name]          # a KeyError here is a default that no schema declares
        given = overrides[name].value if name in overrides else default
        value = _as_schema_type(given, spec)
        # rclpy types a parameter by the value it is declared with: check it is the
        # schema's type first
        if _ros_type(value) != _ROS_TYPES[spec.type]:
            article = "an" if spec.type == "integer" else "a"
            raise ParameterError(f"{where}: {name} must be {article} "
                                 f"{spec.type.replace('_', ' ')}, got {value!r}")
        try:
            param = node.declare_parameter(name, value, parameter_descriptor(spec),
                                           ignore_override=True)
        except InvalidParameterValueException:
            raise ParameterError(f"{where}: {name} = {value!r} must be {spec.constraint} "
                                 f"({spec.description})") from None
        values[name] = plain_value(param.value)

    def as_schema_types(params: list[RclpyParameter]) -> list[RclpyParameter]:
        # a run-time change is converted as a params file's value is (`ros2 param set ...
        # 20` for a real parameter is that real; rclpy would refuse the type)
        out = []
        for p in params:
            value = _as_schema_type(p.value, specs[p.name]) if p.name in specs else p.value
            out.append(p if _ros_type(value) == p.type_.value
                       else RclpyParameter(p.name, value=value))
        return out

    node.add_pre_set_parameters_callback(as_schema_types)
    return unflatten(values)


def plain_value(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    return value
