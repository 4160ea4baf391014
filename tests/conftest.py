"""Test session set-up: single-threaded BLAS and headless MuJoCo before numpy/mujoco load, and the
order that keeps `make test` (pytest-xdist, one worker per core, `--dist loadfile`) fast:

- each test file runs whole on one worker (`--dist loadfile`, set by the Makefile), so a
  module-scoped fixture (a Monte Carlo of several simulated runs) is built once, not once per
  worker that runs one of its tests;
- the heaviest files (HEAVIEST, by the seconds `make test --durations` measured, heaviest first)
  are collected first, then the other files holding a test marked `slow` (a Monte Carlo, a
  reproduction, commands interrupted in subprocesses: about 10 s or more), each file whole, in its
  own order, so the long ones start early and the short ones fill the end (longest first: the two
  workers end together); no test depends on the order (every draw is seeded in the test,
  docs/testing.md).
"""
import os

for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")
os.environ.setdefault("MUJOCO_GL", "egl")


#: the costliest test files, heaviest first (measured on a fresh clone's `make test`, 2 workers);
#: only their order depends on this list
HEAVIEST = ("test_plugins", "test_phase_scenario", "test_faults", "test_visnav_scenario", "test_fuzz",
            "test_visnav_filters", "test_cluster", "test_window", "test_golden", "test_coop_scenario",
            "test_api", "test_denied", "test_loop")


def pytest_collection_modifyitems(config, items):
    slow = {item.module.__name__ for item in items if item.get_closest_marker("slow") is not None}
    rank = {name: i for i, name in enumerate(HEAVIEST)}
    # stable: files kept whole, in order
    items.sort(key=lambda item: (rank.get(item.module.__name__, len(rank)), item.module.__name__ not in slow))
