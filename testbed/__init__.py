"""MuJoCo physics-in-the-loop testbed for cooperative navigation of UAV swarms.

The Python API (docs/api.md), loaded on first use so that `import testbed` stays light:

    load_scenario(name_or_path, overrides=None, *, seed=None, motion=None, duration=None) -> Scenario
    run(scenario, out=None, *, force=False, plots=True, progress=False, video=False) -> Run
    load_run(path) -> Run
    builtin_scenarios() -> list[str]
    score(estimates, run, *, name="estimates") -> dict   # testbed.plugins.Estimate objects
    view(run_dir, out=None, *, force=False, spawn=False) -> Path   # a Rerun recording (the viz extra)
    Run, Stream, Truth: the classes those return (testbed.api, testbed.stream, testbed.truth)

Importing it has no side effect; the command line sets its environment (testbed.environment).
"""

import importlib

__version__ = "0.1.0"

_API = ("Run", "Stream", "Truth", "builtin_scenarios", "load_run", "load_scenario", "run", "score", "view")
__all__ = [*_API, "__version__"]


def __getattr__(name: str):
    if name in _API:
        # lazy: testbed.api loads numpy and mujoco, which `import testbed` must not; by name, as
        # a facade: testbed.api depends on modules that read testbed.__version__ (no real cycle)
        return getattr(importlib.import_module("testbed.api"), name)
    raise AttributeError(f"module 'testbed' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_API})
