"""Test session set-up: single-threaded BLAS and headless MuJoCo before numpy/mujoco load, and the
order and grouping that keep `make test` (pytest-xdist, one worker per core) fast:

- a test that uses a module-scoped fixture joins the xdist group of that fixture, so the fixture
  (a Monte Carlo of several simulated runs) is computed once, on one worker, not once per worker
  (`--dist loadgroup`, set by the Makefile; without xdist the marks change nothing);
- the modules holding a test marked `slow` are collected first (each module whole, in its own
  order), so the long ones start early and the short ones fill the end; no test depends on the
  order (every draw is seeded in the test, docs/testing.md).
"""
import os

import pytest

for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")
os.environ.setdefault("MUJOCO_GL", "egl")


def _module_fixture(item: pytest.Item) -> str | None:
    """The first (by name) module- or session-scoped fixture of the test's own module that the test
    uses, or None (pytest's own, such as tmp_path_factory, cost nothing to build twice)."""
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return None
    for name in sorted(info.name2fixturedefs):
        defs = info.name2fixturedefs[name]
        own = defs and getattr(defs[-1].func, "__module__", None) == item.module.__name__
        if own and defs[-1].scope in ("module", "session") and name in item.fixturenames:
            return name
    return None


def pytest_collection_modifyitems(config, items):
    for item in items:
        shared = _module_fixture(item)
        if shared is not None:
            item.add_marker(pytest.mark.xdist_group(f"{item.module.__name__}::{shared}"))
    # modules with a slow test first, each module's tests kept together and in order (a module
    # fixture is built once per worker only while its tests run back to back)
    slow = {item.module.__name__ for item in items if item.get_closest_marker("slow") is not None}
    items.sort(key=lambda item: item.module.__name__ not in slow)  # stable
