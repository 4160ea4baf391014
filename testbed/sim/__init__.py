"""The simulator: the MuJoCo scene and its physics accessors (world), the loop (simulate), the
flown vehicles (control, thrust, disturbance), the reference trajectories they follow (reference)
and the network between them (network). The sensors that read the physics are testbed.sensors.
Nothing here imports an estimator or the scoring (tests/test_architecture.py)."""
