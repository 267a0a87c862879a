"""
rclpy glue: declare a :class:`~.params.ParamSpec` schema and validate every change.

``declare_schema`` declares each spec with a :class:`ParameterDescriptor` (description,
range, read-only) and normalises the start-up values; ``ParameterBinder`` registers the
pre-set (integer -> double, unit vectors, empty array -> typed empty array), on-set
(merge + validate, reject with the reason) and post-set (install) callbacks, so a
multi-value set applies atomically. An empty array means "default" everywhere: at start-up
``-p effort_limits:=[]`` or ``theta_min: []`` in a params file (what ``ros2 param dump``
writes) arrive untyped and are read as the default; a set of ``[]`` keeps the parameter
declared. Boolean arrays are refused for double arrays (numpy would read them as 0/1).
"""
from __future__ import annotations

import array
import math
from typing import Any, Callable, Generic, Iterable, Sequence, TypeVar

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.node import Node
from rclpy.parameter import Parameter

from ...core.config.params import check_stability, ParameterValidationError, ParamSpec

__all__ = ['ParameterBinder', 'check_values', 'declare_schema', 'descriptor_for',
           'normalise_value']

T = TypeVar('T')
_Type = Parameter.Type
_ROS_TYPE = {'double': _Type.DOUBLE, 'double_array': _Type.DOUBLE_ARRAY, 'integer': _Type.INTEGER,
             'string': _Type.STRING, 'string_array': _Type.STRING_ARRAY, 'bool': _Type.BOOL,
             'integer_array': _Type.INTEGER_ARRAY}


def descriptor_for(spec: ParamSpec) -> ParameterDescriptor:
    """Descriptor of ``spec``; doubles are dynamically typed so integers are accepted."""
    d = ParameterDescriptor(name=spec.name, description=spec.description,
                            read_only=spec.read_only)
    if spec.kind in ('double', 'double_array'):
        d.dynamic_typing = True
        d.additional_constraints = f'{spec.kind} (integers are converted)' + (
            ', > 0' if spec.positive else '')
    elif spec.kind == 'integer_array':  # [] has no type of its own (rclpy: a byte array)
        d.dynamic_typing = True
        d.additional_constraints = 'integer_array'
    else:
        d.type = _ROS_TYPE[spec.kind].value
    bounded = spec.lo is not None and spec.hi is not None
    if bounded and spec.kind == 'double':
        d.floating_point_range = [FloatingPointRange(from_value=float(spec.lo),
                                                     to_value=float(spec.hi), step=0.0)]
    elif bounded and spec.kind == 'integer':
        d.integer_range = [IntegerRange(from_value=int(spec.lo), to_value=int(spec.hi), step=0)]
    return d


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def normalise_value(spec: ParamSpec, value: Any, unit: Iterable[str] = ()) -> Any:
    """
    Integers -> floats for double(_array) specs, arrays -> lists, unit vectors normalised.

    Values that do not fit are returned unchanged, for validation to reject with a reason.
    """
    if spec.kind == 'double' and _is_number(value):
        return float(value)
    if spec.kind == 'double_array' and isinstance(value, (list, tuple, array.array)):
        if len(value) == 0:
            return []
        if not all(_is_number(x) for x in value):
            return value
        out = [float(x) for x in value]
        norm = math.sqrt(sum(x * x for x in out))
        if spec.name in unit and len(out) == 3 and math.isfinite(norm) and norm > 1e-9:
            out = [x / norm for x in out]
        return out
    if spec.kind in ('string_array', 'integer_array') and isinstance(
            value, (list, tuple, array.array)):
        return list(value)
    return value


def _refuse_bools(spec: ParamSpec, value: Any) -> None:
    """Refuse a double array holding booleans (numpy would take them as 0 and 1)."""
    if spec.kind == 'double_array' and isinstance(value, (list, tuple)) and any(
            isinstance(x, bool) for x in value):
        raise ParameterValidationError(f'{spec.name} must be an array of numbers, got '
                                       f'booleans {list(value)}')


def _unset_means_default(spec: ParamSpec, value: Any) -> Any:
    """``[]`` from a params file or ``-p NAME:=[]`` arrives untyped (None): the default."""
    if value is None and spec.kind in ('double_array', 'string_array', 'integer_array'):
        return list(spec.default)
    return value


def check_values(specs: Sequence[ParamSpec], values: dict[str, Any]) -> dict[str, Any]:
    """
    Check what needs no robot model: types, finiteness, ranges, eq. (29).

    Returns ``values``; raises :class:`~.params.ParameterValidationError` with the reason.
    """
    for spec in specs:
        value = values.get(spec.name, spec.default)
        _refuse_bools(spec, value)
        if spec.kind == 'double':
            if not _is_number(value) or not math.isfinite(value):
                raise ParameterValidationError(f'{spec.name} must be a finite number, '
                                               f'got {value!r}')
            if (spec.positive and not value > 0.0) or (
                    spec.lo is not None and not spec.lo <= value <= spec.hi):
                raise ParameterValidationError(f'{spec.name} = {value:g} is outside '
                                               f'[{spec.lo:g}, {spec.hi:g}]'
                                               + (' or not > 0' if spec.positive else ''))
        elif spec.kind == 'double_array' and not all(
                _is_number(x) and math.isfinite(x) for x in value):
            raise ParameterValidationError(f'{spec.name} must be an array of finite numbers, '
                                           f'got {value!r}')
    if 'n' in values:
        n = values['n']
        if len(n) != 3 or not math.sqrt(sum(x * x for x in n)) > 1e-9:
            raise ParameterValidationError(f'n must be 3 numbers, not all zero, got {list(n)}')
    if {'lambda1', 'lambda2', 'k_max'} <= set(values):
        check_stability(values['lambda1'], values['lambda2'], values['k_max'])
    return values


def _parameter(spec: ParamSpec, value: Any) -> Parameter:
    """Make a Parameter of the schema's type when ``value`` fits it ([] stays typed)."""
    try:
        return Parameter(spec.name, _ROS_TYPE[spec.kind], value)
    except (TypeError, ValueError):
        return Parameter(spec.name, value=value)


def declare_schema(node: Node, schema: Sequence[ParamSpec],
                   unit: Iterable[str] = ()) -> dict[str, Any]:
    """
    Declare every spec (``--params-file``/``-p`` overrides apply); return ``{name: value}``.

    Declaring runs no pre-set callback, so the value is normalised and set again (typed:
    ``[]`` would stay a byte array) before read-only is applied.
    Raises :class:`~.params.ParameterValidationError` for an out-of-range value.
    """
    values = {}
    for spec in schema:
        final = descriptor_for(spec)
        writable = descriptor_for(spec)
        writable.read_only = False
        raw = node.declare_parameter(spec.name, spec.default, writable).value
        value = normalise_value(spec, _unset_means_default(spec, raw), unit)
        _refuse_bools(spec, value)
        result = node.set_parameters([_parameter(spec, value)])[0]
        if not result.successful:
            raise ParameterValidationError(f'{spec.name}: {result.reason}')
        if spec.read_only:
            node.set_descriptor(spec.name, final)
        values[spec.name] = value
    return values


class ParameterBinder(Generic[T]):
    """
    Validate every set of the schema's parameters; install the result after it is set.

    Parameters
    ----------
    node : rclpy.node.Node
        Node whose schema parameters were declared with :func:`declare_schema`.
    schema : sequence of ParamSpec
        The specs to watch; other parameters (``use_sim_time`` ...) pass through.
    validate : callable
        All schema values ``{name: value}`` -> validated object, or raises
        :class:`~.params.ParameterValidationError` with the reason.
    apply : callable
        Installs the validated object once the values are stored (post-set).
    unit : iterable of str
        double_array specs normalised to unit length.

    """

    def __init__(self, node: Node, schema: Sequence[ParamSpec], validate: Callable[[dict], T],
                 apply: Callable[[T], None], unit: Iterable[str] = ()) -> None:
        self.node, self.validate, self.apply = node, validate, apply
        self.specs = {s.name: s for s in schema}
        self.unit = tuple(unit)
        self._pending: T | None = None
        node.add_pre_set_parameters_callback(self.pre_set)
        node.add_on_set_parameters_callback(self.on_set)
        node.add_post_set_parameters_callback(self.post_set)

    def pre_set(self, parameters: list[Parameter]) -> list[Parameter]:
        """Convert integer (array) values of double (array) specs; normalise unit vectors."""
        out = []
        for p in parameters:
            spec = self.specs.get(p.name)
            try:
                if spec is not None and p.type_ == _Type.NOT_SET:
                    p = _parameter(spec, _unset_means_default(spec, None))
                if spec is not None and p.type_ != _Type.NOT_SET:
                    p = _parameter(spec, normalise_value(spec, p.value, self.unit))
            except Exception as exc:  # noqa: BLE001 - never raise into the parameter service
                self.node.get_logger().error(f'pre-set of {p.name} failed: {exc}')
            out.append(p)
        return out

    def on_set(self, parameters: list[Parameter]) -> SetParametersResult:
        """Merge with the current values and validate; reject (nothing applied) on error."""
        self._pending = None
        proposed = {p.name: p for p in parameters if p.name in self.specs}
        if not proposed:
            return SetParametersResult(successful=True)
        try:
            values = {n: normalise_value(s, self.node.get_parameter(n).value)
                      for n, s in self.specs.items()}
            for name, p in proposed.items():
                if p.type_ == _Type.NOT_SET:
                    raise ParameterValidationError(f'{name} cannot be undeclared')
                values[name] = normalise_value(self.specs[name], p.value, self.unit)
                _refuse_bools(self.specs[name], values[name])
            self._pending = self.validate(values)
        except Exception as err:  # noqa: BLE001 - the reason goes back to the caller
            return SetParametersResult(successful=False, reason=str(err) or repr(err))
        return SetParametersResult(successful=True)

    def post_set(self, parameters: list[Parameter]) -> None:
        """Install the set validated by :meth:`on_set` (one call per atomic set)."""
        pending, self._pending = self._pending, None
        try:
            if pending is not None:
                self.apply(pending)
        except Exception as exc:  # noqa: BLE001 - never raise into the parameter service
            self.node.get_logger().error(f'installing parameters failed: {exc!r}')
