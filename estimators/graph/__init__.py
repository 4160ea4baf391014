"""The factor-graph library: one home for the factors, the robust losses and the solvers of every
factor graph of the testbed (its SO(3) exp/log, the only one of the tree: estimators.so3).

- factors: range, GNSS (position prior) and motion (white-noise acceleration) factors, their
  Jacobians and whitening, the range variance inflated by a neighbour's broadcast;
- losses: Huber and Cauchy as IRLS weights (the only Huber of the tree);
- lm: the one Gauss-Newton / Levenberg-Marquardt iteration (one problem, or a batch of
  independent ones at once), Nielsen's damping rule, and the round iteration of the distributed
  message-passing solvers; every solver's result carries its Report;
- linear, banded: SPD solves with an observability (gauge) check, the normal equations (sparse for
  one problem, dense batched for many), marginal covariances (dense, banded, selected inverse),
  the block-tridiagonal chain solve;
- model: a general graph of points, poses (SO(3) from estimators.so3), biases and motion factors;
- batch: many small epoch graphs solved at once (recorded data); warmstart: their start;
- flooding, gbp: the accelerated distributed variants of seed 001.
Built on it: estimators.factor_graph (seed 001, centralized and distributed), batch (the epochs of
recorded data), flooding and gbp, and estimators.window (the sliding window, centralized and
distributed).

Never imports mujoco, testbed or gtsam.
"""
