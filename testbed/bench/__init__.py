"""Benchmarks (`testbed bench physics|sensors|estimators [--json FILE]`), not tests.

- `swarm`: the one benchmark-swarm scenario builder;
- `physics`: flown-mode and bare `mj_step` real-time factors;
- `sensors`: the sensor suite's cost on an 18-vehicle swarm and the camera pixel path;
- `estimators`: per-step cost of our filters and solvers next to filterpy and GTSAM;
- `run.bench`: runs one family, prints its table and writes the JSON.
"""
