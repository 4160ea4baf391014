"""The simulator: the MuJoCo scene and its physics accessors (world), the loop (simulate), the
flown vehicles (control, thrust, disturbance) and the network between them (network). The
reference trajectories they follow are the plan, configuration (testbed.reference). The sensors that read the physics are testbed.sensors.
Nothing here imports an estimator or the scoring (tests/test_architecture.py)."""
