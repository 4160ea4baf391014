"""Estimation library of the testbed: pure numpy/scipy, never imports mujoco or testbed.

Modules:
    core        Gaussian belief, linear Kalman steps, Joseph update, NEES.
"""
