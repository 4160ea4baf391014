"""Strict conversion between TOML tables and frozen dataclasses.

Every configuration object of the testbed is a `@dataclass(frozen=True, kw_only=True, slots=True)`
built only here, at the boundary. An unknown key, a wrong type or an out-of-range value raises
`ConfigError` with one line naming the file, the dotted key and the value; the CLI turns it into
exit code 2.

Supported field types: bool, int, float (an int is accepted), str, Literal[...], tuple[float, ...]
and other homogeneous tuples, nested dataclasses, tuples of dataclasses, `X | None`, and unions of
dataclasses discriminated by a `kind: Literal[...]` field. Range checks live in each dataclass's
`check()` method, which raises `ValueError(key, message)`; `ConfigError` adds the file and path.
"""
from __future__ import annotations

import dataclasses
import types
from typing import Any, Literal, Union, get_args, get_origin, get_type_hints

from testbed.errors import ConfigError


def _fail(file: str, path: str, msg: str) -> ConfigError:
    where = f"{file}: " if file else ""
    return ConfigError(f"{where}{path}: {msg}" if path else f"{where}{msg}")


def _is_union(tp: Any) -> bool:
    return get_origin(tp) in (Union, types.UnionType)


def _convert(tp: Any, value: Any, file: str, path: str) -> Any:
    origin = get_origin(tp)
    if _is_union(tp):
        args = [a for a in get_args(tp) if a is not type(None)]
        if value is None and len(args) < len(get_args(tp)):
            return None
        if len(args) == 1:
            return _convert(args[0], value, file, path)
        if all(dataclasses.is_dataclass(a) for a in args):
            if not isinstance(value, dict) or "kind" not in value:
                raise _fail(file, path, "expected a table with a 'kind' key")
            kinds = {get_args(get_type_hints(a)["kind"])[0]: a for a in args}
            if value["kind"] not in kinds:
                raise _fail(file, f"{path}.kind", f"unknown kind {value['kind']!r}; expected one of {sorted(kinds)}")
            return _convert(kinds[value["kind"]], value, file, path)
        raise TypeError(f"unsupported union {tp}")
    if origin is Literal:
        if value not in get_args(tp):
            raise _fail(file, path, f"invalid value {value!r}; expected one of {list(get_args(tp))}")
        return value
    if origin is tuple:
        args = get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise _fail(file, path, f"expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, file, f"{path}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise _fail(file, path, f"expected {len(args)} values, got {len(value)}: {value!r}")
        return tuple(_convert(a, v, file, f"{path}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
    if dataclasses.is_dataclass(tp):
        return from_dict(tp, value, file, path)
    if tp is bool:
        if not isinstance(value, bool):
            raise _fail(file, path, f"expected true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _fail(file, path, f"expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise _fail(file, path, f"expected a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise _fail(file, path, f"expected a string, got {value!r}")
        return value
    raise TypeError(f"unsupported field type {tp} at {path}")


def from_dict(cls: type, data: Any, file: str = "", path: str = "") -> Any:
    """Build dataclass `cls` from a TOML table, strictly. Raises ConfigError."""
    if not isinstance(data, dict):
        raise _fail(file, path, f"expected a table, got {data!r}")
    hints = get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for key in data:
        if key not in fields:
            raise _fail(file, f"{path}.{key}" if path else key, f"unknown key (known: {', '.join(sorted(fields))})")
    kwargs = {}
    for name, f in fields.items():
        sub = f"{path}.{name}" if path else name
        if name in data:
            kwargs[name] = _convert(hints[name], data[name], file, sub)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise _fail(file, sub, "missing required key")
    obj = cls(**kwargs)
    check = getattr(obj, "check", None)
    if check is not None:
        try:
            check()
        except ValueError as e:
            key, msg = e.args if len(e.args) == 2 else ("", e.args[0])
            sub = f"{path}.{key}" if path and key else (key or path)
            raise _fail(file, sub, msg) from None
    return obj


def to_dict(obj: Any) -> Any:
    """Dataclass -> plain TOML-ready table, every field written out (None fields omitted)."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj) if getattr(obj, f.name) is not None}
    if isinstance(obj, tuple):
        return [to_dict(v) for v in obj]
    return obj


def set_dotted(data: dict, dotted: str, raw: str, file: str) -> None:
    """Apply a CLI override `dotted.key=value` to a TOML table in place.

    The key must already exist (after defaults are written out); the value is parsed as TOML, or
    taken as a string if it does not parse.
    """
    import tomllib

    keys = dotted.split(".")
    node: Any = data
    for i, k in enumerate(keys[:-1]):
        if isinstance(node, list) and k.isdigit() and int(k) < len(node):
            node = node[int(k)]
        elif isinstance(node, dict) and k in node:
            node = node[k]
        else:
            raise ConfigError(f"{file}: --set {dotted}: no key {'.'.join(keys[: i + 1])!r} in the scenario")
    last = keys[-1]
    if not isinstance(node, dict) or last not in node:
        raise ConfigError(f"{file}: --set {dotted}: no key {dotted!r} in the scenario")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    node[last] = value


def check(cond: bool, key: str, msg: str) -> None:
    """Raise the ValueError(key, msg) that from_dict turns into a ConfigError."""
    if not cond:
        raise ValueError(key, msg)

