"""The `[pipeline]` table of each paper's scenarios.

- `config`: the `[pipeline]` table of each kind (dataclasses and validation only; the scenario
  schema imports it, so it must stay free of compute code, scipy and mujoco). Its kind names the
  paper's default estimators (testbed.plugins.defaults), which take its keys as their settings.
"""
