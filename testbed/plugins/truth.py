"""Truth of a body or site at arbitrary times, interpolated from a run log (scoring only).

The log holds each vehicle's base-body pose and twist at the logged ticks (`time`, `truth/pos`,
`truth/quat`, `truth/vel`, `truth/omega`). At a time t between two logged ticks: position and
velocity are interpolated linearly, attitude by slerp, body rates linearly; exact at a logged
tick (every sensor sample is one). A site adds its lever arm l (body frame):
p_site = p + R l, v_site = v + R (omega x l); a site's attitude is its vehicle's.
Relative to a vehicle J (Estimate.frame "uavJ"): R_J^T (p - p_J), R_J^T (v - v_J), R_J^T R.
Errors: position/velocity estimate minus truth (in the estimate's frame); attitude
log(R_true^T R_est) (rad, body).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from testbed.plugins.api import Context


class Truth:
    """Interpolated truth of one run. log: the run log; context: for the site lever arms."""

    def __init__(self, log: dict[str, np.ndarray], context: Context):
        self.t = np.asarray(log["time"], float)
        self.pos, self.vel, self.omega = log["truth/pos"], log["truth/vel"], log["truth/omega"]
        self.quat = log["truth/quat"]
        self.index = {name: i for i, name in enumerate(context.vehicles)}
        self.sites = context.sites
        self._slerp: dict[int, Slerp] = {}  # per vehicle, built on first use

    def times(self, target: str) -> np.ndarray:
        """The instants (K,) s the truth of `target` is logged at (every vehicle's: the log's ticks)."""
        return self.t

    def _lin(self, arr: np.ndarray, i: int, t: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(t, self.t, arr[:, i, a]) for a in range(arr.shape[2])], axis=1)

    def _rot(self, i: int, t: np.ndarray) -> Rotation:
        if self.t.size == 1:
            return Rotation.concatenate([Rotation.from_quat(self.quat[:, i], scalar_first=True)] * t.size)
        if i not in self._slerp:
            self._slerp[i] = Slerp(self.t, Rotation.from_quat(self.quat[:, i], scalar_first=True))
        return self._slerp[i](np.clip(t, self.t[0], self.t[-1]))

    def at(self, target: str, quantity: str, t: np.ndarray, frame: str = "world") -> np.ndarray:
        """True value (K, 3) of position (m) / velocity (m/s), or (K, 4) wxyz attitude, at times t (K,),
        in the world frame or relative to vehicle `frame` (module docstring)."""
        x = self._world(target, quantity, t)
        if frame == "world":
            return x
        return relative(x, quantity, self._rot(self.index[frame], t), lambda: self._world(frame, quantity, t))

    def _world(self, target: str, quantity: str, t: np.ndarray) -> np.ndarray:
        body, arm = self.sites[target] if target in self.sites else (target, None)
        arm = None if arm is None else np.array(arm, float)  # a writable copy (scipy needs one)
        i = self.index[body]
        if quantity == "attitude":
            return self._rot(i, t).as_quat(scalar_first=True)
        base = self._lin(self.pos if quantity == "position" else self.vel, i, t)
        if arm is None:
            return base
        R = self._rot(i, t)
        if quantity == "position":
            return base + R.apply(arm)
        return base + R.apply(np.cross(self._lin(self.omega, i, t), arm))


def relative(x: np.ndarray, quantity: str, R: Rotation, x_frame) -> np.ndarray:
    """World-frame truth x (K, 3) or (K, 4) wxyz expressed relative to a vehicle with attitude R (K
    rotations) and, for position/velocity, world value x_frame() (K, 3): R^T (x - x_frame), R^T R_x."""
    if quantity == "attitude":
        return (R.inv() * Rotation.from_quat(x, scalar_first=True)).as_quat(scalar_first=True)
    return R.inv().apply(x - x_frame())


def errors(truth: Truth, target: str, quantity: str, t: np.ndarray, value: np.ndarray, frame: str = "world") -> np.ndarray:
    """Estimate minus truth (K, 3): m, m/s, or the attitude error rotation vector (rad, body)."""
    true = truth.at(target, quantity, t, frame)
    if quantity != "attitude":
        return value - true
    r_est = Rotation.from_quat(value, scalar_first=True)
    return (Rotation.from_quat(true, scalar_first=True).inv() * r_est).as_rotvec()
