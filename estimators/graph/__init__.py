"""Factor-graph machinery shared by the seed 001 solver (estimators.factor_graph) and the general
graph (points, poses, biases, motion factors): robust losses, sparse SPD solves with a gauge
(observability) check, marginal covariances, the Levenberg-Marquardt step control.

Never imports mujoco, testbed or gtsam.
"""
