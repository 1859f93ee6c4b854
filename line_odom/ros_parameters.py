"""The node's ROS parameters: every engine setting and node parameter declared with a descriptor built from its row
(description, range, read_only unless the row says a running node may change it), the preset supplying the defaults,
read once into NodeSettings and the engine's Config, and refused at runtime: none is applied live. A bad value is a
ParameterSetupError naming it (the node exits 2 with that one line)."""
from __future__ import annotations

import re

from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.parameter import Parameter
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType,
                                SetParametersResult)

from line_odom.node_parameters import NODE_PARAMETERS, NodeSettings
from line_odom_core.config import ConfigEntry, config_schema, load_config

INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1
_PTYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
           float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING,
           list: ParameterType.PARAMETER_DOUBLE_ARRAY}


def parameter_descriptor(entry: ConfigEntry) -> ParameterDescriptor:
    """The ROS descriptor of an engine setting or node parameter: its description; its range as an IntegerRange or
    FloatingPointRange (ROS ranges are closed: an open end or a 0 that switches the feature off is in
    additional_constraints, which always says what the parameter accepts, unit included); read_only unless a running
    node may change it."""
    d = ParameterDescriptor(name=entry.name, type=_PTYPES[entry.type], description=entry.description,
                            read_only=not entry.runtime,
                            additional_constraints="" if entry.expected in ("bool", "str") else entry.expected)
    if entry.type in (int, float) and (entry.min is not None or entry.max is not None):
        lo = 0 if entry.zero_is_off and (entry.min is None or entry.min > 0) else entry.min
        if entry.type is int:
            d.integer_range = [IntegerRange(from_value=int(lo if lo is not None else INT64_MIN),
                                            to_value=int(entry.max if entry.max is not None else INT64_MAX), step=0)]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(lo if lo is not None else -1e308),
                                                         to_value=float(entry.max if entry.max is not None else 1e308),
                                                         step=0.0)]
    return d


PRESET_PARAMETER = ConfigEntry("preset", str, "kitti_hdl64", "engine + node defaults: a preset name (kitti_hdl64, "
                               "tum_kinect, vlp16, ouster_os128) or a ROS 2 parameter YAML path; individual "
                               "parameters override it")


class ParameterSetupError(ValueError):
    """A parameter has a bad value or type; the message names it and says what is expected."""


class UndeclaredParameterError(ParameterNotDeclaredException):
    """rclpy's own message for this lists no name; this one names them."""

    def __init__(self, names: list[str]):
        Exception.__init__(self, f"no parameter {', '.join(repr(n) for n in names)} on this node (line_odom declares "
                                 f"its parameters at start-up; list them with ros2 param list)")


def one_line(text: str) -> str:
    return re.sub(r"\s*\n\s*", "; ", str(text).strip())


class ParameterMixin:
    """On an rclpy Node (or LifecycleNode): declare_and_load() fills ``settings`` and ``config``."""

    def _coerce_overrides(self, names_types: dict[str, type]) -> None:
        """ROS parameter files often write 2 for 2.0 (and [0, 0, 0] for doubles); accept those for double
        parameters instead of failing on the type."""
        overrides = getattr(self, "_parameter_overrides", None)
        if not isinstance(overrides, dict):
            return
        for name, want in names_types.items():
            p = overrides.get(name)
            if p is None:
                continue
            if want is float and p.type_ == Parameter.Type.INTEGER:
                overrides[name] = Parameter(name, Parameter.Type.DOUBLE, float(p.value))
            elif want is list and p.type_ == Parameter.Type.INTEGER_ARRAY:
                overrides[name] = Parameter(name, Parameter.Type.DOUBLE_ARRAY, [float(v) for v in p.value])

    def _declare(self, name, default, descriptor):
        if self.has_parameter(name):  # a managed node configured again reads the values it declared
            return self.get_parameter(name).value
        try:
            return self.declare_parameter(name, default, descriptor).value
        except Exception as err:  # rclpy raises several exception types for bad overrides
            raise ParameterSetupError(f"parameter {name!r}: {one_line(err)}") from None

    def declare_and_load(self) -> None:
        """Declares every parameter (the preset gives the defaults), reads them into ``self.settings`` and
        ``self.config``; ParameterSetupError naming the parameter or file when one is bad."""
        preset = self._declare("preset", PRESET_PARAMETER.default, parameter_descriptor(PRESET_PARAMETER))
        try:
            base = load_config(preset)
        except Exception as err:  # noqa: BLE001 - YAML syntax, encoding, I/O and schema errors alike: one line
            raise ParameterSetupError(f"parameter 'preset' ({preset!r}): {one_line(err)}") from None
        try:
            preset_node = NodeSettings.from_mapping(base.extra, strict=False).as_dict()
        except ValueError as err:
            raise ParameterSetupError(f"preset {base.source}: {err}") from None
        unknown = sorted(k for k in base.extra if k not in preset_node and k not in ("use_sim_time", "preset"))
        if unknown:
            self.get_logger().warning(f"preset {base.source}: ignoring unknown keys {unknown}")

        schema = config_schema()
        self._coerce_overrides({**{e.name: e.type for e in schema}, **{p.name: p.type for p in NODE_PARAMETERS}})

        node_values = {}
        for p in NODE_PARAMETERS:
            default = preset_node[p.name]
            node_values[p.name] = self._declare(p.name, [float(v) for v in default] if p.type is list else default,
                                                parameter_descriptor(p))
        try:
            self.settings = NodeSettings.from_mapping(node_values)
        except ValueError as err:
            raise ParameterSetupError(str(err)) from None

        engine_values = {}
        for e in schema:
            engine_values[e.name] = self._declare(e.name, base[e.name], parameter_descriptor(e))
        try:
            self.config = load_config(preset, engine_values)
        except ValueError as err:
            raise ParameterSetupError(str(err)) from None

        declared = {"preset", "use_sim_time"} | set(node_values) | set(engine_values)
        overrides = getattr(self, "_parameter_overrides", {}) or {}
        stray = sorted(n for n in overrides if n not in declared and not n.startswith("qos_overrides."))
        if stray:
            self.get_logger().warning(f"ignoring unknown parameters {stray} (typo?)")
        if not getattr(self, "_parameter_guards", False):
            self.add_pre_set_parameters_callback(self._refuse_undeclared)
            self.add_on_set_parameters_callback(self._refuse_change)
            self._parameter_guards = True

    def _refuse_undeclared(self, parameters: list[Parameter]) -> list[Parameter]:
        unknown = [p.name for p in parameters if not self.has_parameter(p.name)]
        if unknown:
            raise UndeclaredParameterError(unknown)
        return parameters

    def _refuse_change(self, parameters: list[Parameter]) -> SetParametersResult:
        """No parameter is applied live (the engine, the subscriptions and the clock are built from them once):
        a change at runtime, use_sim_time included, is refused naming it rather than accepted and ignored."""
        names = ", ".join(p.name for p in parameters)
        return SetParametersResult(successful=False, reason=(
            f"{names}: read-only while the node runs (line_odom reads its parameters once, at start-up; restart it "
            f"with the new value, e.g. -p {parameters[0].name}:=...)" if parameters else "no parameter given"))

    def log_parameters(self) -> None:
        lines = [f"  preset = {self.config.source}"]
        lines += [f"  {k} = {v}" for k, v in self.settings.as_dict().items()]
        lines += [f"  {k} = {v}" for k, v in self.config.as_dict().items()]
        lines.append(f"  use_sim_time = {self.get_parameter('use_sim_time').value}")
        self.get_logger().info("parameters:\n" + "\n".join(lines))
