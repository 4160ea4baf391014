"""Warm start of per-epoch solves: a constant-velocity, constant-body-rate fit to recent solutions.

An epoch's solve converges in few iterations when it starts near its optimum. Extrapolating the
last two solutions (a finite difference over one epoch) multiplies their noise by the ratio of the
prediction horizon to the epoch spacing: with 0.1 m position noise, 0.1 s apart, predicted 1.6 s
ahead, the start is off by ~2 m. A least-squares line through the solutions of a window of K
epochs averages that noise out (velocity error ~ sigma / sqrt(sum (t_k - t_mean)^2)).

Per variable (vectorized over V variables), from solutions at times t_k (K,) s:
- position p(t) = a + b (t - t_mean), a, b the least-squares line through p_k (m world, m/s);
- attitude R(t) = R_K exp([c + d (t - t_K)]x), c, d the least-squares line through the body-frame
  rotation vectors w_k = Log(R_K^T R_k) (rad, rad/s; |w_k| < pi: the window must be shorter than
  half a turn; where a log is not finite, the attitude R_K is held).
One solution: constant pose. Never imports mujoco, testbed or gtsam.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.so3 import so3_exp, so3_log

__all__ = ["MotionFit", "fit_motion"]


@dataclass(frozen=True, slots=True)
class MotionFit:
    """Constant-velocity and body-rate model of V variables: t_mean, t_last s; a (V, 3) m world at
    t_mean; b (V, 3) m/s world; R_last (V, 3, 3) body-to-world at t_last; c (V, 3) rad body at t_last;
    d (V, 3) rad/s body."""

    t_mean: float
    t_last: float
    a: np.ndarray
    b: np.ndarray
    R_last: np.ndarray
    c: np.ndarray
    d: np.ndarray

    def predict(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Poses at times t (E,) s: positions (E, V, 3) m world, rotations (E, V, 3, 3)."""
        t = np.asarray(t, float)[:, None, None]
        p = self.a + self.b * (t - self.t_mean)
        R = self.R_last @ so3_exp(self.c + self.d * (t - self.t_last))
        return p, R


def _line(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares y ~ y0 + slope x for centred x (K,) and y (K, V, 3): (y0, slope) (V, 3); the
    slope is zero for a single point."""
    sxx = float(x @ x)
    slope = np.einsum("k,kvi->vi", x, y) / sxx if sxx > 0 else np.zeros(y.shape[1:])
    return y.mean(axis=0), slope


def fit_motion(t: np.ndarray, p: np.ndarray, R: np.ndarray) -> MotionFit:
    """Fit the model of the module docstring to solutions at times t (K,) s (K >= 1, increasing):
    positions p (K, V, 3) m world, rotations R (K, V, 3, 3) body-to-world."""
    t = np.asarray(t, float)
    if t.ndim != 1 or t.size == 0 or p.shape[0] != t.size or R.shape[0] != t.size:
        raise ValueError(f"fit_motion: need K >= 1 solutions with one time each, got t {t.shape}, p {p.shape}, R {R.shape}")
    t_mean = float(t.mean())
    a, b = _line(t - t_mean, p)
    R_last = R[-1]
    w = so3_log(np.swapaxes(R_last, -1, -2)[None] @ R)  # (K, V, 3) body frame of the last solution
    x = t - t_mean
    w0, d = _line(x, w)
    c = w0 + d * (t[-1] - t_mean)  # the line's value at t_last
    held = ~np.all(np.isfinite(c) & np.isfinite(d), axis=-1)  # a log at half a turn: hold the attitude
    c[held], d[held] = 0.0, 0.0
    return MotionFit(t_mean, float(t[-1]), a, b, R_last, c, d)
