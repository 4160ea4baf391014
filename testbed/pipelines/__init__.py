"""Estimator pipelines: turn a run log into estimates, metrics and plots, one per paper.

- `config`: the `[pipeline]` table of each kind (dataclasses and validation only; the scenario
  schema imports it, so it must stay free of compute code, scipy and mujoco);
- `phase`, `visnav`, `bandwidth`, `coop`: the compute side of each kind, a function
  `run(scenario, log, plots_dir) -> dict`;
- `registry`: `run_pipeline`, which runs the scenario's kind.

Pipelines read measurement streams and configured "known" quantities; truth only for scoring.
"""
