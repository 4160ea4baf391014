"""Paper-mode data generators: seeded synthetic truth and measurements, pure numpy, no physics.

One module per paper, each importing only numpy/scipy and `estimators` (never mujoco):
- `bandwidth` (seed 000): the paper's linear network, y_i = C_i x + v_i, vectorized Monte Carlo;
- `coop` (seed 001): connected swarms, GNSS fixes and UWB ranges of one epoch;
- `phase` (seed 003): hovering masters in a formation, the eq. 31 follower, ranges and rates;
- `visnav` (seed 004): leader/follower trajectories, both IMUs and the LED lines of sight.

Used by `testbed reproduce` (paper mode), `testbed bench estimators` and the tests. For the
physics-in-the-loop counterparts run the paper's scenarios.
"""
