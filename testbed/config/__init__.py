"""Strict conversion between TOML tables and frozen dataclasses.

Every configuration object of the testbed is a `@dataclass(frozen=True, kw_only=True, slots=True)`
built only here, at the boundary. An unknown key, a wrong type or an out-of-range value raises
`ConfigError` with one line naming the file, the dotted key and the value; the CLI turns it into
exit code 2.

Supported field types: bool, int, float (an int is accepted), str, Literal[...], tuple[float, ...]
and other homogeneous tuples, nested dataclasses, tuples of dataclasses, `X | None`, and unions of
dataclasses discriminated by a `kind: Literal[...]` field.

Every number is finite and at most `MAX_MAGNITUDE` in size, and a non-zero float at least
`MIN_MAGNITUDE`: `_convert` refuses NaN, +-inf, anything larger and denormal-like specks for every
int and float field (no key of the testbed has a meaning for them; a
key that one day gives inf a meaning must say so in its dataclass docstring and be exempted
here), and `in_range` refuses non-finite values of fields set in code. So a product or a square of
two configuration numbers never overflows, and no later computation meets a NaN from the input.

Validation cannot be skipped: every configuration dataclass checks its values in `__post_init__`
(so `dataclasses.replace` re-checks too) with `require` / `in_range`, which raise `FieldError`
naming the key relative to that dataclass. `from_dict` re-raises it with the file and the full
dotted path (`world.anchors[2]`, `sensors.uwb.noise`).
"""
from __future__ import annotations

import dataclasses
import functools
import math
import re
import tomllib
import types
from typing import Any, Literal, Union, get_args, get_origin, get_type_hints

from testbed.errors import ConfigError, FieldError


# Largest magnitude of any configuration number (SI units): 1e9 m, s, Hz, m^2/s^3, ... is beyond
# every physical use of every key, and squares (1e18) and products stay far from overflow.
MAX_MAGNITUDE = 1e9
# Smallest magnitude of a non-zero float: below every physical value of a key (1e-9 rad/s gyro
# biases) and far from underflow when squared or inverted (5e-324 as a period overflows 1 / T).
MIN_MAGNITUDE = 1e-12


def _fail(file: str, path: str, msg: str, value: object = None) -> FieldError:
    return FieldError(file, path, value, msg)


def is_union(tp: Any) -> bool:
    return get_origin(tp) in (Union, types.UnionType)


def _convert(tp: Any, value: Any, file: str, path: str) -> Any:
    origin = get_origin(tp)
    if is_union(tp):
        args = [a for a in get_args(tp) if a is not type(None)]
        if value is None and len(args) < len(get_args(tp)):
            return None
        if len(args) == 1:
            return _convert(args[0], value, file, path)
        if all(dataclasses.is_dataclass(a) for a in args):
            if not isinstance(value, dict) or "kind" not in value:
                raise _fail(file, path, "expected a table with a 'kind' key")
            kinds = {get_args(_hints(a)["kind"])[0]: a for a in args}
            if not isinstance(value["kind"], str) or value["kind"] not in kinds:
                raise _fail(file, f"{path}.kind", f"unknown kind {value['kind']!r}; expected one of {sorted(kinds)}")
            return _convert(kinds[value["kind"]], value, file, path)
        raise TypeError(f"unsupported union {tp}")
    if origin is Literal:
        if value not in get_args(tp):
            raise _fail(file, path, f"invalid value {value!r}; expected one of {list(get_args(tp))}", value)
        return value
    if origin is tuple:
        args = get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise _fail(file, path, f"expected a list, got {value!r}", value)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, file, f"{path}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise _fail(file, path, f"expected {len(args)} values, got {len(value)}: {value!r}", value)
        return tuple(_convert(a, v, file, f"{path}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
    if dataclasses.is_dataclass(tp):
        return from_dict(tp, value, file, path)
    if tp is bool:
        if not isinstance(value, bool):
            raise _fail(file, path, f"expected true or false, got {value!r}", value)
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _fail(file, path, f"expected an integer, got {value!r}", value)
        if abs(value) > MAX_MAGNITUDE:
            raise _fail(file, path, f"{value} is out of range (at most {MAX_MAGNITUDE:g} in magnitude)", value)
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise _fail(file, path, f"expected a number, got {value!r}", value)
        if not (math.isfinite(value) and (value == 0 or MIN_MAGNITUDE <= abs(value) <= MAX_MAGNITUDE)):
            raise _fail(file, path, f"must be a finite number, 0 or of magnitude in [{MIN_MAGNITUDE:g}, {MAX_MAGNITUDE:g}], got {value!r}", value)
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise _fail(file, path, f"expected a string, got {value!r}", value)
        return value
    if tp is dict:  # a free table (e.g. an estimator's params), passed through as parsed
        if not isinstance(value, dict):
            raise _fail(file, path, f"expected a table, got {value!r}", value)
        return value
    raise TypeError(f"unsupported field type {tp} at {path}")


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    """The resolved field types of dataclass `cls` (typing.get_type_hints, two thirds of a
    scenario's loading time when resolved anew each time; the classes never change)."""
    return get_type_hints(cls)


def from_dict(cls: type, data: Any, file: str = "", path: str = "") -> Any:
    """Build dataclass `cls` from a TOML table, strictly. Raises ConfigError."""
    if not isinstance(data, dict):
        raise _fail(file, path, f"expected a table, got {data!r}")
    hints = _hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for key in data:
        if key not in fields:
            raise _fail(file, f"{path}.{key}" if path else key, f"unknown key (known: {', '.join(sorted(fields))})", data[key])
    kwargs = {}
    for name, f in fields.items():
        sub = f"{path}.{name}" if path else name
        if name in data:
            kwargs[name] = _convert(hints[name], data[name], file, sub)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise _fail(file, sub, "missing required key")
    try:
        return cls(**kwargs)
    except FieldError as e:  # raised by __post_init__ with a key relative to cls
        raise FieldError(file, join_key(path, e.key), e.value, e.reason) from None


def to_dict(obj: Any) -> Any:
    """Dataclass -> plain TOML-ready table, every field written out (None fields omitted)."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj) if getattr(obj, f.name) is not None}
    if isinstance(obj, (tuple, list)):
        return [to_dict(v) for v in obj]
    return obj


_KEY_PART = re.compile(r"[A-Za-z_][A-Za-z0-9_-]*|\d+")
_INDEX = re.compile(r"\[(\d+)\]")


def parse_key(dotted: str) -> list[str | int] | None:
    """`world.obstacles[0].size` -> ['world', 'obstacles', 0, 'size']; None if malformed.

    List elements are addressed by a 0-based index in brackets (`trajectory.offsets[2]`,
    `world.anchors[1][2]`) or, as before, by a dotted number (`world.anchors.1`).
    """
    out: list[str | int] = []
    for part in dotted.split("."):
        name, _, rest = part.partition("[")
        rest = "[" + rest if rest else ""
        if not _KEY_PART.fullmatch(name) or _INDEX.sub("", rest):
            return None
        out.append(int(name) if name.isdigit() else name)
        out.extend(int(i) for i in _INDEX.findall(rest))
    return out


def format_key(parts: list[str | int]) -> str:
    """Inverse of parse_key, indices in brackets: ['world', 'anchors', 1] -> 'world.anchors[1]'."""
    return "".join(f"[{p}]" if isinstance(p, int) else (f".{p}" if i else p) for i, p in enumerate(parts))


def set_dotted(data: dict, dotted: str, raw: Any, file: str) -> None:
    """Apply a CLI override `dotted.key=value` to a TOML table in place.

    dotted: a key that must already exist once defaults are written out; list elements by 0-based
    index, `world.obstacles[0].size` or `trajectory.offsets[2]` (see parse_key). raw: a string is
    parsed as a TOML value, or taken as a string if it does not parse; any other Python value
    (from the Python API) is used as it is. The new table is validated by the caller (from_dict).
    """
    parts = parse_key(dotted)
    if not parts:
        raise ConfigError(f"{file}: --set {dotted}: malformed key (expected e.g. world.truth_rate or world.obstacles[0].size)")
    node: Any = data
    for i, k in enumerate(parts):
        last = i == len(parts) - 1
        if isinstance(node, list) and isinstance(k, int):
            if k >= len(node):
                raise ConfigError(f"{file}: --set {dotted}: no key {format_key(parts[: i + 1])!r} in the scenario "
                                  f"({format_key(parts[:i])} has {len(node)} element{'s' if len(node) != 1 else ''})")
        elif not (isinstance(node, dict) and isinstance(k, str) and k in node):
            shown = format_key(parts[: i + 1]) if not last else format_key(parts)
            raise ConfigError(f"{file}: --set {dotted}: no key {shown!r} in the scenario")
        if last:
            break
        node = node[k]
    if isinstance(raw, str):
        value = parse_value(raw)
    else:
        value = to_dict(raw)
    node[parts[-1]] = value


# ------------------------------------------------------------------------------ validation


def key(default: Any = dataclasses.MISSING, *, unit: str = "", range: str = "", doc: str = "",
        lo: float | None = None, hi: float | None = None, lo_open: bool = False, hi_open: bool = False,
        factory: Any = dataclasses.MISSING) -> Any:
    """A configuration field with its metadata: unit, one-line doc, and allowed range.

    The range is an interval (lo, hi, lo_open, hi_open as in_range), which `check_fields`
    enforces (call it in the dataclass's `__post_init__`) and `check_key` checks on one value
    alone, or, for a check that is not an interval, words (`range`) for `testbed schema` and
    `testbed estimators NAME`; a field checked by its own in_range call declares it there.
    factory: a default_factory in place of default (a mutable default such as a table).
    """
    meta = {k: v for k, v in (("unit", unit), ("range", range), ("doc", doc)) if v}
    if lo is not None or hi is not None:
        meta["interval"] = (lo, hi, lo_open, hi_open)
    if factory is not dataclasses.MISSING:
        return dataclasses.field(default_factory=factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def check_fields(obj: object) -> None:
    """The interval check of every field of dataclass obj declared with `key(lo=..., hi=...)`
    (a None value, for an optional key, is not checked). Raises FieldError naming the field."""
    for f in dataclasses.fields(obj):
        bounds = f.metadata.get("interval")
        if bounds is not None and getattr(obj, f.name) is not None:
            in_range(obj, f.name, *bounds[:2], lo_open=bounds[2], hi_open=bounds[3], unit=f.metadata.get("unit", ""))


def check_key(cls: type, name: str, value: Any, file: str = "") -> Any:
    """One key of dataclass `cls` alone, without building cls: it exists, its value has the
    field's type and lies in the field's declared interval (`key(lo=..., hi=...)`). Returns the
    converted value. Raises FieldError naming the key and the value. What a field's check
    compares with other fields is left to `from_dict` of the whole table."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    if name not in fields:
        raise _fail(file, name, f"unknown key (known: {', '.join(sorted(fields))})", value)
    converted = _convert(_hints(cls)[name], value, file, name)
    bounds = fields[name].metadata.get("interval")
    if bounds is not None and converted is not None:
        try:
            _check_interval(name, converted, *bounds, unit=fields[name].metadata.get("unit", ""))
        except FieldError as e:
            raise FieldError(file, e.key, e.value, e.reason) from None
    return converted


def read_toml_file(path, what: str, directory_hint: str) -> dict:
    """The table of the TOML file at path (a `what` file: "spec", "calibration"); ConfigError, one
    line naming the file, when it is missing, a directory (directory_hint: what to name instead),
    not UTF-8 or not valid TOML."""
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such {what} file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory; {directory_hint}") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: not valid TOML: {e}") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a UTF-8 text file") from None


def parse_value(raw: str) -> Any:
    """A command-line value (`--set`, `--param`): parsed as a TOML value, else the string itself."""
    try:
        return tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        return raw


def join_key(prefix: str, key: str) -> str:
    """Dotted path of `key` below `prefix` ('' on either side allowed; `[i]` indices glue on)."""
    if not prefix or not key:
        return prefix or key
    return f"{prefix}{key}" if key.startswith("[") else f"{prefix}.{key}"


def require(cond: bool, key: str, value: object, reason: str) -> None:
    """The check of a configuration dataclass's `__post_init__`: raise FieldError unless cond.

    key: the field tested, relative to the dataclass (`from_dict` prefixes the path and the file);
    value: the offending value; reason: what is wrong, for a person.
    """
    if not cond:
        raise FieldError("", key, value, reason)


# While testbed.config.schema.declared_ranges builds configurations, every in_range call records here
# {(dataclass, field): (lo, hi, lo_open, hi_open, unit)}; None (no recording) otherwise.
RANGES: dict[tuple[type, str], tuple] | None = None


def in_range(obj: object, key: str, lo: float | None = None, hi: float | None = None, *,
             lo_open: bool = False, hi_open: bool = False, unit: str = "") -> None:
    """Require field `key` of obj (a number, or every number of a tuple) to lie in an interval.

    lo, hi: bounds (None = unbounded); lo_open, hi_open: exclude the bound. The one place for
    "a number in a range" checks: a NaN or an infinity is refused here too (whatever the bounds),
    so a value set in code is held to what `from_dict` enforces on a file.
    Also the declaration of the range and unit that `testbed schema` prints (see RANGES).
    """
    if RANGES is not None:
        RANGES.setdefault((type(obj), key), (lo, hi, lo_open, hi_open, unit))
    _check_interval(key, getattr(obj, key), lo, hi, lo_open, hi_open, unit)


def _check_interval(key: str, value: Any, lo: float | None, hi: float | None, lo_open: bool = False,
                    hi_open: bool = False, unit: str = "") -> None:
    """in_range's check of one value (a number or a tuple of numbers): FieldError unless inside."""
    values = value if isinstance(value, tuple) else (value,)
    ok = all(math.isfinite(v) for v in values) and all((lo is None or (v > lo if lo_open else v >= lo)) and (hi is None or (v < hi if hi_open else v <= hi)) for v in values)
    if ok:
        return
    want = describe_range(lo, hi, lo_open, hi_open, unit)
    got = list(value) if isinstance(value, tuple) else value
    finite = "" if all(math.isfinite(v) for v in values) else "finite and "
    raise FieldError("", key, value, f"must be {finite}{want}, got {got}")


def describe_range(lo: float | None, hi: float | None, lo_open: bool = False, hi_open: bool = False, unit: str = "") -> str:
    """An interval for people: 'positive', '>= 0 m', 'in [0, 1)', '<= 5 s'."""
    u = f" {unit}" if unit else ""
    if hi is None and lo is None:
        return "any"
    if hi is None:
        return ("positive" if lo == 0 else f"> {lo:g}{u}") if lo_open else f">= {lo:g}{u}"
    if lo is None:
        return f"< {hi:g}{u}" if hi_open else f"<= {hi:g}{u}"
    return f"in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}{u}"


def whole_ratio(a: float, b: float) -> bool:
    """Is a / b a whole number >= 1 (to 1e-9)? For rates that must divide each other.

    False for a ratio beyond 1e12 or not finite (no rate of the testbed divides another that often).
    """
    ratio = a / b
    if not (math.isfinite(ratio) and abs(ratio) <= 1e12):
        return False
    return abs(ratio - round(ratio)) < 1e-9 and round(ratio) >= 1


# ------------------------------------------------------------------------------ for people


def type_name(tp: Any) -> str:
    """A field annotation for people: float, "a" | "b", [float, float, float], list of int."""
    if is_union(tp):
        return " or ".join(type_name(a) for a in get_args(tp) if a is not type(None))
    if get_origin(tp) is Literal:
        return type(get_args(tp)[0]).__name__
    if get_origin(tp) is tuple:
        args = get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return f"list of {type_name(args[0])}"
        return "[" + ", ".join(type_name(a) for a in args) + "]"
    if dataclasses.is_dataclass(tp):
        return "table"
    return tp.__name__


def show_value(v: Any) -> str:
    """A value for people, as TOML writes it: true, "text", 0.1, [1, 2]."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, tuple):
        return "[" + ", ".join(show_value(x) for x in v) + "]"
    return str(v)
