"""Settings dataclasses as the single definition of every parameter.

A field made with :func:`setting` carries its default, unit, range, choices and
description; everything else is derived from it: validation (:class:`Settings`
checks every field on construction), the ROS parameter table
(:func:`parameters`: names, ROS units, ranges), ``--help`` (:func:`help_text`)
and the conversion of ROS parameter values into settings (:func:`from_params`).
A unit conversion is declared once, e.g. ``unit="rad", ros_unit="deg"``: the
field holds radians, the ROS parameter (and YAML) degrees. A field holding
another :class:`Settings` (``nested``) lends its parameters to the parent.
No ROS import: ``ros/params.py`` turns the table into parameter descriptors.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar, cast

import yaml

from .errors import SettingsError

__all__ = [
    "Setting",
    "Parameter",
    "Settings",
    "setting",
    "nested",
    "parameters",
    "from_params",
    "to_params",
    "unknown_params",
    "flatten_params",
    "help_text",
    "read_params_file",
    "yaml_value",
    "params_from_ros_args",
]

_KEY = "rls_setting"
_NESTED = "rls_nested"
ParamValue = bool | int | float | str
_KIND_TEXT = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}
S = TypeVar("S", bound="Settings")

# ROS unit -> (field value -> ROS value, ROS value -> field value), for a field in radians.
_CONVERSIONS: dict[tuple[str, str], tuple[Callable[[float], float], Callable[[float], float]]] = {
    ("rad", "deg"): (math.degrees, math.radians),
}


@dataclass(frozen=True)
class Setting:
    """What a settings field means (kept in the field's metadata by :func:`setting`).

    Attributes:
        doc: one line: what the value does, and the source of the default where it has one.
        unit: unit of the field's value ("" for none).
        low, high: inclusive bounds in the field's unit (None: unbounded).
        low_open, high_open: the bound itself is excluded (e.g. a positive width).
        choices: allowed strings of a text setting.
        ros_name: the ROS parameter's name where it differs from the field's.
        ros_unit: the ROS parameter's unit where it differs from ``unit`` (``"deg"`` for ``"rad"``).
        read_only: cannot change once the node is configured (needs a new precomputation).
    """

    doc: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] = ()
    ros_name: str | None = None
    ros_unit: str | None = None
    read_only: bool = False


def setting(
    default: Any,
    doc: str,
    *,
    unit: str = "",
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    choices: tuple[str, ...] = (),
    ros_name: str | None = None,
    ros_unit: str | None = None,
    read_only: bool = False,
) -> Any:
    """A dataclass field with its meaning; see :class:`Setting` for the arguments."""
    if ros_unit is not None and (unit, ros_unit) not in _CONVERSIONS:
        raise ValueError(f"no conversion from {unit!r} to {ros_unit!r}")
    meta = Setting(doc, unit, low, high, low_open, high_open, tuple(choices), ros_name, ros_unit, read_only)
    return dataclasses.field(default=default, metadata={_KEY: meta})


def nested(factory: Callable[[], Settings], prefix: str = "") -> Any:
    """A field holding another settings object whose parameters join the parent's.

    With ``prefix`` its parameters are named ``<prefix>.<name>`` (a composite method holding other
    methods' settings whose names would clash: ``mcl.max_particles``, ``pil.max_range``). The
    defaults are those of the object ``factory`` returns (a composite may start from other values).
    """
    return dataclasses.field(default_factory=factory, metadata={_NESTED: prefix or True})


@dataclass(frozen=True)
class Parameter:
    """One ROS parameter derived from a settings field.

    Attributes:
        name: ROS parameter name.
        path: field names from the top settings class down to the field.
        default: default in the ROS unit; its Python type is the parameter's type.
        unit: the ROS parameter's unit.
        low, high: inclusive bounds in the ROS unit (None: unbounded).
        setting: the field's :class:`Setting`.
    """

    name: str
    path: tuple[str, ...]
    default: ParamValue
    unit: str
    low: float | None
    high: float | None
    setting: Setting

    @property
    def kind(self) -> type:
        return type(self.default)

    def to_ros(self, value: Any) -> ParamValue:
        """A field value in the ROS unit."""
        convert = _CONVERSIONS.get((self.setting.unit, self.setting.ros_unit or self.setting.unit))
        return convert[0](value) if convert else value

    def from_ros(self, value: Any) -> Any:
        """A ROS value (type-checked, ints accepted for floats) in the field's unit.

        Raises:
            SettingsError: naming the parameter, the value and the expected type.
        """
        kind = self.kind
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if kind is bool and not isinstance(value, bool) or kind is not bool and isinstance(value, bool):
            raise SettingsError(f"parameter {self.name} must be {_KIND_TEXT[kind]}, got {value!r}")
        if not isinstance(value, kind):
            raise SettingsError(f"parameter {self.name} must be {_KIND_TEXT[kind]}, got {value!r}")
        checked = cast(ParamValue, value)
        self.check(checked)
        convert = _CONVERSIONS.get((self.setting.unit, self.setting.ros_unit or self.setting.unit))
        return convert[1](float(checked)) if convert else checked

    def check(self, value: ParamValue) -> None:
        """Refuse a ROS value outside the range or the choices, naming the parameter and the range.

        Raises:
            SettingsError: ``parameter NAME must be in RANGE UNIT, got VALUE``.
        """
        s = self.setting
        if isinstance(value, str):
            if s.choices and value not in s.choices:
                raise SettingsError(f"parameter {self.name} must be one of {', '.join(s.choices)}; got {value!r}")
            return
        if isinstance(value, bool):
            return
        if not math.isfinite(value):
            raise SettingsError(f"parameter {self.name} must be finite, got {value!r}")
        too_low = self.low is not None and (value < self.low or (s.low_open and value == self.low))
        too_high = self.high is not None and (value > self.high or (s.high_open and value == self.high))
        if too_low or too_high:
            unit = f" {self.unit}" if self.unit else ""
            raise SettingsError(f"parameter {self.name} must be in {self.range_text()}{unit}, got {value!r}")

    def range_text(self) -> str:
        """``[0..1]``, ``(0..]``, ``{a, b}`` or ``""``."""
        s = self.setting
        if s.choices:
            return "{" + ", ".join(s.choices) + "}"
        if self.low is None and self.high is None:
            return ""
        low = "" if self.low is None else f"{self.low:g}"
        high = "" if self.high is None else f"{self.high:g}"
        return f"{'(' if s.low_open else '['}{low}..{high}{')' if s.high_open else ']'}"

    def help_line(self) -> str:
        unit = f" [{self.unit}]" if self.unit else ""
        bounds = self.range_text()
        return f"  {self.name} = {self.default!r}{unit}{' ' + bounds if bounds else ''}: {self.setting.doc}"


class Settings:
    """Base of every settings dataclass: each field is checked against its :class:`Setting` on construction.

    A subclass adds cross-field checks in :meth:`validate` (raise :class:`SettingsError`).
    """

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):  # type: ignore[arg-type]
            meta = field.metadata.get(_KEY)
            if meta is not None:
                _check_value(type(self).__name__, field.name, getattr(self, field.name), field.default, meta)
        self.validate()

    def validate(self) -> None:
        """Checks that involve several fields (none by default)."""


def _check_value(owner: str, name: str, value: Any, default: Any, meta: Setting) -> None:
    where = f"{owner}.{name}"
    kind = type(default)
    if kind is bool:
        if not isinstance(value, bool):
            raise SettingsError(f"{where} must be true or false, got {value!r}")
        return
    if kind is str:
        if not isinstance(value, str):
            raise SettingsError(f"{where} must be a string, got {value!r}")
        if meta.choices and value not in meta.choices:
            raise SettingsError(f"{where} must be one of {', '.join(meta.choices)}; got {value!r}")
        return
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or (kind is int and not isinstance(value, numbers.Integral)):
        raise SettingsError(f"{where} must be {'an integer' if kind is int else 'a number'}, got {value!r}")
    number = float(value)
    if not math.isfinite(number):
        raise SettingsError(f"{where} must be finite, got {value!r}")
    too_low = meta.low is not None and (number < meta.low or (meta.low_open and number == meta.low))
    too_high = meta.high is not None and (number > meta.high or (meta.high_open and number == meta.high))
    if too_low or too_high:
        shown = Parameter(name, (name,), default, meta.unit, meta.low, meta.high, meta).range_text()
        unit = f" {meta.unit}" if meta.unit else ""
        raise SettingsError(f"{where} must be in {shown}{unit}, got {value!r}")


def _fields(cls: type) -> Iterator[tuple[dataclasses.Field[Any], Any]]:
    for field in dataclasses.fields(cls):
        yield field, field.metadata


def _nested_default(field: dataclasses.Field[Any]) -> Any:
    """The default settings object a :func:`nested` field holds (its factory's: defaults of its own)."""
    factory = field.default_factory
    assert callable(factory), field.name
    return factory()


_TABLES: dict[type, tuple[Parameter, ...]] = {}


def parameters(cls: type[Settings]) -> tuple[Parameter, ...]:
    """Every ROS parameter of a settings class (nested ones flattened), in field order.

    Raises:
        SettingsError: a field without :func:`setting` / :func:`nested`, or a name used twice.
    """
    if cls in _TABLES:
        return _TABLES[cls]
    found: list[Parameter] = []

    def visit(klass: type, defaults: Any, prefix: tuple[str, ...], name_prefix: str) -> None:
        for field, meta in _fields(klass):
            if meta.get(_NESTED):
                label = meta[_NESTED]
                inner = _nested_default(field) if defaults is None else getattr(defaults, field.name)
                visit(type(inner), inner, (*prefix, field.name),
                      f"{name_prefix}{label}." if isinstance(label, str) else name_prefix)
                continue
            info: Setting | None = meta.get(_KEY)
            if info is None:
                raise SettingsError(f"{klass.__name__}.{field.name} has no setting() metadata")
            default = field.default if defaults is None else getattr(defaults, field.name)
            if not isinstance(default, (bool, int, float, str)):
                raise SettingsError(f"{klass.__name__}.{field.name}: default {default!r} is no ROS parameter type")
            probe = Parameter(name_prefix + (info.ros_name or field.name), (*prefix, field.name), default, info.unit,
                              None, None, info)
            low = None if info.low is None else float(probe.to_ros(info.low))
            high = None if info.high is None else float(probe.to_ros(info.high))
            found.append(dataclasses.replace(probe, default=probe.to_ros(default), unit=info.ros_unit or info.unit,
                                             low=low, high=high))

    visit(cls, None, (), "")
    names = [p.name for p in found]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise SettingsError(f"{cls.__name__}: parameter names used twice: {', '.join(twice)}")
    _TABLES[cls] = tuple(found)
    return _TABLES[cls]


def flatten_params(values: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"initial_pose": {"x": 1}}`` -> ``{"initial_pose.x": 1}`` (params files nest dotted names)."""
    flat: dict[str, Any] = {}
    for key, value in values.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten_params(value, f"{name}."))
        else:
            flat[name] = value
    return flat


def from_params(cls: type[S], values: Mapping[str, Any]) -> S:
    """Settings from ROS parameter values (ROS names and units); missing ones keep their defaults.

    Names the class does not know are ignored (see :func:`unknown_params`).

    Raises:
        SettingsError: a value of the wrong type or out of range, naming the parameter.
    """
    flat = flatten_params(values)
    tree: dict[tuple[str, ...], dict[str, Any]] = {}
    for param in parameters(cls):
        if param.name in flat:
            tree.setdefault(param.path[:-1], {})[param.path[-1]] = param.from_ros(flat[param.name])
    return _build(cls, (), tree)


def _build(cls: type[S], prefix: tuple[str, ...], tree: dict[tuple[str, ...], dict[str, Any]],
           base: S | None = None) -> S:
    """``cls`` (or ``base``, a nested field's default) with the values of ``tree`` under ``prefix``."""
    kwargs = dict(tree.get(prefix, {}))
    for field, meta in _fields(cls):
        if meta.get(_NESTED):
            inner = _nested_default(field)
            kwargs[field.name] = _build(type(inner), (*prefix, field.name), tree, inner)
    return cls(**kwargs) if base is None else cast(S, dataclasses.replace(cast(Any, base), **kwargs))


def to_params(settings: Settings) -> dict[str, ParamValue]:
    """The ROS parameter values (ROS names and units) of a settings object."""
    out: dict[str, ParamValue] = {}
    for param in parameters(type(settings)):
        value: Any = settings
        for name in param.path:
            value = getattr(value, name)
        out[param.name] = param.to_ros(value)
    return out


def unknown_params(cls: type[Settings], values: Mapping[str, Any]) -> list[str]:
    """The names in ``values`` that are no parameter of ``cls``."""
    known = {p.name for p in parameters(cls)}
    return sorted(name for name in flatten_params(values) if name not in known)


def help_text(*classes: type[Settings]) -> str:
    """One line per parameter: name, default, unit, range, description."""
    return "\n".join(p.help_line() for cls in classes for p in parameters(cls))


def read_params_file(path: str | Path, node_name: str) -> dict[str, Any]:
    """The flattened ``ros__parameters`` of ``node_name`` (or ``/**``) in a ROS 2 params file.

    A section for the node's name wins over ``/**`` for the same parameter, as ROS merges them.

    Raises:
        SettingsError: a missing or unreadable file, or a file with no section for the node.
    """
    path = Path(path)
    try:
        loaded = yaml.safe_load(path.read_text()) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise SettingsError(f"cannot read params file {str(path)!r}: {exc}") from exc
    if not isinstance(loaded, dict):
        raise SettingsError(f"params file {str(path)!r} is not a mapping of node names")
    # Wildcards first, so that the node's own section wins (ROS' order of precedence).
    names = sorted((key for key in loaded if str(key).lstrip("/") in ("**", "*", node_name)),
                   key=lambda key: str(key).lstrip("/") == node_name)
    if not names:
        raise SettingsError(
            f"params file {str(path)!r} has no section for node {node_name!r} (nor '/**'): ROS would ignore it"
        )
    merged: dict[str, Any] = {}
    for name in names:
        section = loaded[name]
        params = section.get("ros__parameters", {}) if isinstance(section, dict) else None
        if not isinstance(params, dict):
            raise SettingsError(f"params file {str(path)!r}: section {name!r} has no ros__parameters mapping")
        merged.update(flatten_params(params))
    return merged


def yaml_value(raw: str, where: str) -> Any:
    """``raw`` read as one YAML value, as ROS reads ``-p name:=value``.

    Raises:
        SettingsError: it is no YAML (naming ``where`` and the value).
    """
    try:
        return yaml.safe_load(raw)
    except yaml.YAMLError as exc:
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise SettingsError(f"{where}: the value {raw!r} is not YAML ({problem})") from None


def params_from_ros_args(argv: Sequence[str], node_name: str) -> dict[str, Any]:
    """Parameter values from ``--ros-args`` (``-p NAME:=VALUE``, ``--params-file FILE``), without rclpy.

    Later arguments override earlier ones, as in ROS 2; values are parsed as YAML, as ``ros2 run`` does.

    Raises:
        SettingsError: a malformed ``-p`` or an unreadable params file.
    """
    values: dict[str, Any] = {}
    args = list(argv)
    index, in_ros_args = 0, False
    while index < len(args):
        arg = args[index]
        if arg == "--ros-args":
            in_ros_args = True
        elif arg == "--":
            in_ros_args = False
        elif in_ros_args and arg in ("-p", "--param") and index + 1 < len(args):
            index += 1
            name, sep, raw = args[index].partition(":=")
            if not sep:
                raise SettingsError(f"parameter argument {args[index]!r} must be NAME:=VALUE")
            values[name] = yaml_value(raw, f"parameter argument {args[index]!r}") if raw else ""
        elif in_ros_args and arg == "--params-file" and index + 1 < len(args):
            index += 1
            values.update(read_params_file(args[index], node_name))
        elif in_ros_args and arg in ("-r", "--remap", "--log-level", "-e", "--enclave") and index + 1 < len(args):
            index += 1
        index += 1
    return values
