"""The exact truth of any site or body of a run, recomputed from the logged MuJoCo state.

`log.npz` stores `qpos` (K, nq) and `qvel` (K, nv) at every log instant and `scene.xml` is the
exact model simulated, so the pose and velocity of anything in the scene at those instants follow
by MuJoCo's forward kinematics (mj_kinematics, mj_comPos, mj_comVel) and mj_objectVelocity.
"""
from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np


@dataclass(frozen=True, kw_only=True, slots=True)
class Truth:
    """Pose and velocity of one site or body at the K log instants.

    name: as asked (`uav3`, `uav3/uwb`, `anchor2`); kind: "body" or "site".
    time: (K,) s. pos: (K, 3) m, world frame (ENU). quat: (K, 4) wxyz, frame-to-world (the
    site's or body's frame). vel: (K, 3) m/s, linear velocity of that point, world frame.
    omega: (K, 3) rad/s, angular velocity in the site's or body's own frame.
    """

    name: str
    kind: str
    time: np.ndarray
    pos: np.ndarray
    quat: np.ndarray
    vel: np.ndarray
    omega: np.ndarray


def resolve(model: mujoco.MjModel, name: str) -> tuple[mujoco.mjtObj, int, str]:
    """(object type, id, kind) of a site or body by name; a vehicle `uavI` is its body `uavI/base`.

    Sites win over bodies of the same name. KeyError naming the name if neither exists.
    """
    for obj, kind, full in ((mujoco.mjtObj.mjOBJ_SITE, "site", name), (mujoco.mjtObj.mjOBJ_BODY, "body", name),
                            (mujoco.mjtObj.mjOBJ_BODY, "body", f"{name}/base")):
        oid = mujoco.mj_name2id(model, obj, full)
        if oid >= 0:
            return obj, oid, kind
    raise KeyError(f"no site or body named {name!r} in the scene (e.g. 'uav1', 'uav1/uwb', 'uav1/ant1', 'anchor1')")


def object_truth(model: mujoco.MjModel, name: str, time: np.ndarray, qpos: np.ndarray, qvel: np.ndarray) -> Truth:
    """Truth of site or body `name` at the states qpos (K, nq), qvel (K, nv) logged at time (K,) s."""
    obj, oid, kind = resolve(model, name)
    data = mujoco.MjData(model)
    K = len(time)
    pos, quat, vel, omega = np.empty((K, 3)), np.empty((K, 4)), np.empty((K, 3)), np.empty((K, 3))
    res = np.empty(6)
    for k in range(K):
        data.qpos[:], data.qvel[:] = qpos[k], qvel[k]
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        mujoco.mj_comVel(model, data)
        if kind == "site":
            pos[k] = data.site_xpos[oid]
            R = data.site_xmat[oid].reshape(3, 3)
            mujoco.mju_mat2Quat(quat[k], data.site_xmat[oid])
        else:
            pos[k] = data.xpos[oid]
            R = data.xmat[oid].reshape(3, 3)
            quat[k] = data.xquat[oid]
        mujoco.mj_objectVelocity(model, data, obj, oid, res, 0)  # [angular, linear], world axes
        vel[k] = res[3:]
        omega[k] = R.T @ res[:3]
    return Truth(name=name, kind=kind, time=time, pos=pos, quat=quat, vel=vel, omega=omega)
