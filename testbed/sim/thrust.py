"""External wrenches of the vehicles during flight: rotor thrust (joint route) and the disturbance.

With the joint rotor route (testbed.sim.world.rotor_route) the rotor actuators carry only their
moments; the thrust force, T = ctrl1 + .. + ctrl4 (N) along body z, is written here to the vehicle
bodies' xfrc_applied (world frame, at the centre of mass) before every acceleration stage, from
the attitude of the position stage just computed: the same force the site transmission applies,
in a cost linear in the vehicle count. The disturbance wrench (testbed.sim.disturbance, held over a
tick) is added to it, never overwritten by it.
"""
from __future__ import annotations

import mujoco
import numpy as np

from testbed.sim.world import Physics


class BodyForces:
    """The vehicles' xfrc_applied, rewritten before each acceleration stage (`apply`).

    held: (N, 6) world force (N) and torque (N m) at the centre of mass held over the tick
    (the disturbance; zero otherwise), set with `hold`.
    """

    def __init__(self, physics: Physics):
        v = physics.views()
        self.joint = physics.rotor_route == "joint"
        self.ctrl, self.xfrc = v.ctrl, v.xfrc
        self.body_z = v.rotation[:, :, 2]  # (N, 3) view: third column of body-to-world
        self.held = np.zeros((physics.n, 6))
        self._disturbed = False
        self._thrust = np.empty(physics.n)

    def hold(self, index: np.ndarray, wrench: np.ndarray) -> None:
        """Hold wrench (D, 6) on vehicles index (D,) (0-based) until the next call."""
        self.held[index] = wrench
        self._disturbed = True

    def apply(self) -> None:
        """Write xfrc_applied = thrust along body z (joint route) + held wrench. Call after the
        position stage (xmat current) and after the controller has written ctrl."""
        if self.joint:
            np.sum(self.ctrl, axis=1, out=self._thrust)
            np.multiply(self._thrust[:, None], self.body_z, out=self.xfrc[:, :3])
            if self._disturbed:
                self.xfrc[:, :3] += self.held[:, :3]
                self.xfrc[:, 3:] = self.held[:, 3:]
        elif self._disturbed:
            self.xfrc[:] = self.held

    def step(self, model: mujoco.MjModel, data: mujoco.MjData, nstep: int) -> None:
        """nstep physics steps holding ctrl and the held wrench (thrust direction following the
        attitude at every step with the joint route)."""
        if not self.joint:
            mujoco.mj_step(model, data, nstep=nstep)
            return
        for _ in range(nstep):
            mujoco.mj_step1(model, data)
            self.apply()
            mujoco.mj_step2(model, data)
