"""Simulated sensors computed from the MuJoCo state: imu, uwb, phase, gnss, camera.

- `config`: the `[sensors.*]` tables (dataclasses and validation; loaded by the scenario schema,
  so free of mujoco and OpenCV); `presets`: the error figures a `preset` key fills in;
- `imu`, `uwb`, `phase`, `gnss`, `camera`: one sensor each (`base.Sensor`), `noise`: shared
  error processes;
- `suite.make_sensors(scenario, physics)`: the sensors a scenario carries.

See docs/sensors.md.
"""
