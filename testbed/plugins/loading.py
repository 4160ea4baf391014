"""Finding and loading estimator classes: registered names, `package.module:Name`, `file.py:Name`.

Registered estimators come from the Python entry-point group `testbed.estimators` (a package
declares `[project.entry-points."testbed.estimators"] name = "module:Class"`). The built-ins are
declared there in pyproject.toml (after editing that table, reinstall: `make setup` does).

Everything here runs before a run simulates anything: an entry that cannot be imported or whose
class lacks the protocol is a UsageError (exit 2), naming the entry and what is wrong.
"""
from __future__ import annotations

import functools
import importlib
import importlib.util
import inspect
import sys
import zlib
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from pathlib import Path

from testbed.errors import FieldError, UsageError
from testbed.plugins import params as typed_params
from testbed.config.estimators import EstimatorSpec

GROUP = "testbed.estimators"

@dataclass(frozen=True, slots=True)
class Plugin:
    """A loaded estimator: key (metrics.json name), entry as given, its class and params."""

    key: str
    entry: str
    cls: type
    params: dict = field(default_factory=dict)


def registered() -> dict[str, str]:
    """Every registered estimator: {name: "module:Class"}, from the installed entry points (read
    once per process: a package installed later is seen by the next command)."""
    return dict(_entry_points_of(entry_points))


@functools.lru_cache(maxsize=4)
def _entry_points_of(find) -> tuple[tuple[str, str], ...]:
    """The sorted (name, value) pairs `find(group=GROUP)` gives, read once per finder (scanning
    every installed package's metadata takes milliseconds, and every run resolves its estimators;
    keyed by the finder so that one put in its place is read, not the cache)."""
    return tuple(sorted((ep.name, ep.value) for ep in find(group=GROUP)))


def description(cls: type) -> str:
    """The class's one-line `description`, else the first line of its docstring."""
    text = getattr(cls, "description", None) or (inspect.getdoc(cls) or "").strip()
    return str(text).splitlines()[0] if text else ""


def _import_file(entry: str, path: Path):
    if not path.is_file():
        raise UsageError(f"estimator {entry!r}: no such file {path}")
    # a module name unique per file, so two plugin files with one stem do not collide
    name = f"_testbed_plugin_{path.stem}_{zlib.crc32(str(path.resolve()).encode()):08x}"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses and pickling look the module up by name
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def _is_file(where: str) -> bool:
    """Does the part before ':' of an entry name a file (else a module)?"""
    return where.endswith(".py") or "/" in where or "\\" in where


def entry_file(entry: str) -> Path | None:
    """The file a `path/to/file.py:Name` entry reads (an input of the command), else None."""
    where = registered().get(entry, entry).rpartition(":")[0]
    return Path(where) if where and _is_file(where) else None


def load_class(entry: str) -> type:
    """The class an entry names (registered name, `module:Name` or `path.py:Name`); UsageError if not."""
    target = registered().get(entry, entry)
    where, sep, attr = target.rpartition(":")
    if not sep or not where or not attr:
        known = ", ".join(registered()) or "none"
        raise UsageError(f"estimator {entry!r}: expected a registered name ({known}), package.module:Name or path/to/file.py:Name")
    try:
        if _is_file(where):
            module = _import_file(entry, Path(where))
        else:
            module = importlib.import_module(where)
    except UsageError:
        raise
    except Exception as e:  # the plugin's own import failed: its error, on one line
        raise UsageError(f"estimator {entry!r}: cannot import {where}: {type(e).__name__}: {e}".splitlines()[0]) from None
    cls = getattr(module, attr, None)
    if cls is None:
        raise UsageError(f"estimator {entry!r}: {where} has no {attr!r}")
    check_protocol(entry, cls)
    return cls


def check_protocol(entry: str, cls: object) -> None:
    """A class with a (context, params) constructor and a callable process; finish optional."""
    if not inspect.isclass(cls):
        raise UsageError(f"estimator {entry!r}: not a class but {type(cls).__name__}")
    for method, required in (("process", True), ("finish", False), ("health", False)):
        fn = getattr(cls, method, None)
        if (fn is None and required) or (fn is not None and not callable(fn)):
            raise UsageError(f"estimator {entry!r}: {cls.__name__} lacks the protocol: no method {method}(self, ...)")
    try:
        inspect.signature(cls).bind(None, None)
    except TypeError:
        raise UsageError(f"estimator {entry!r}: {cls.__name__}(context, params) cannot be called with two arguments") from None
    except ValueError:  # no signature available (a builtin): let the run find out
        pass


def check_params(plugin: Plugin) -> None:
    """The plugin's params against its class's `Params` (testbed.plugins.params.check): a mistake
    is a UsageError naming the estimator, the key and the value."""
    try:
        typed_params.check(plugin.cls, dict(plugin.params))
    except FieldError as e:
        raise UsageError(f"estimator {plugin.key!r} ({plugin.entry}) params: {e.key} = {e.value!r}: {e.reason}") from None


def resolve(specs: tuple[EstimatorSpec, ...] | list[EstimatorSpec]) -> list[Plugin]:
    """Load every spec's class and check its params (before simulating); duplicate metrics keys are
    a UsageError."""
    plugins, seen = [], set()
    for s in specs:
        if s.key in seen:
            raise UsageError(f"estimator {s.entry!r}: a second estimator named {s.key!r}; give one a different name")
        seen.add(s.key)
        plugins.append(Plugin(s.key, s.entry, load_class(s.entry), dict(s.params)))
        check_params(plugins[-1])
    return plugins
