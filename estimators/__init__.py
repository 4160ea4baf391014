"""Estimation library of the testbed: pure numpy/scipy, never imports mujoco or testbed.

Modules:
    core            THE estimator interface (Gaussian belief, predict / update), the one driver
                    every filter runs through (drive, Stepper, Track, health counts), the shared
                    numerics (LAPACK Cholesky, Kalman gain, Joseph form, information-form
                    linearized update with the Baarda gate), NEES, chi-square bounds.
    so3             rotation helpers: skew, quaternions (wxyz), SO(3) Exp/Log, ZYX Euler angles.
    phase_model     seed 003: carrier-phase range/range-rate model of three-antenna UAVs.
    phase_ekf       seed 003: 18-state antenna EKF (PhaseEkf), body state, PCRB.
    bandwidth       seed 000: bandwidth-limited distributed fusion (FusionFilter), bound M,
                    selection search.
    factor_graph    seed 001: GNSS + UWB factor graph, centralized and distributed solvers.
    graph           factor-graph machinery: losses, sparse solves with a gauge check, GN/LM,
                    and a general graph (points, poses, biases, height, motion factors).
    gtsam_reference seed 001: the same centralized problem solved with GTSAM (reference only).
    cubature        seed 004: third- and fifth-degree spherical-radial cubature rules.
    sigma_filters   seed 004: EKF, CKF, HCKF, MCKF, RHCF on one model interface.
    visnav          seed 004: INS + LED line-of-sight relative navigation model, CameraFilter.
"""
