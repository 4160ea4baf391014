"""Scene construction with MjSpec, and named accessors to the simulated physics.

`build(scenario)` composes `models/arena.xml` with one `models/quadrotor.xml` per vehicle
(attached with the prefixes uav1/, uav2/, ...), UWB anchor sites `anchor1..` and obstacles
`obstacle1..`, and returns a `Physics`. Nothing outside this module indexes raw MuJoCo arrays by
hand: ask `physics.site_pos("uav3/ant1")` or the vectorized vehicle-state properties (copies),
or `physics.views()` (views into MjData, for per-tick loops).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import mujoco
import numpy as np
from scipy.spatial import cKDTree

from testbed.reference import RefState, evaluate
from testbed.config.scenario import Scenario

MODELS = Path(__file__).resolve().parents[2] / "models"
JOINT_ROUTE_MIN_VEHICLES = 12  # swarms of this size or more use the rotor joint route (measured crossover, docs/models.md)
SEGMENT_MARGIN = 1e-6  # m: bounding boxes grown by this in Physics.segments_may_hit (rounding)
OBSTACLE, FLOOR = -1, -2  # "other" of Physics.contacts_at: an obstacle geom, the rest of the world body
PALETTE = [(0.85, 0.25, 0.2), (0.2, 0.45, 0.85), (0.25, 0.7, 0.3), (0.85, 0.6, 0.15), (0.6, 0.3, 0.75), (0.2, 0.7, 0.75)]


def rotor_route(scenario: Scenario) -> str:
    """How the scene transmits rotor thrust: "site" (site transmission, self-explaining, cost
    quadratic in the vehicle count) or "joint" (free-joint moment gear + thrust in xfrc_applied,
    linear): the joint route for swarms of JOINT_ROUTE_MIN_VEHICLES or more, where it is faster.
    Both motion modes: prescribed runs apply no rotor force, but mj_inverse evaluates the
    transmissions at every logged instant (81 ms per call at 1000 vehicles with the site route)."""
    return "joint" if scenario.vehicles >= JOINT_ROUTE_MIN_VEHICLES else "site"


def _vehicle_template(scenario: Scenario, rotors: str = "site") -> mujoco.MjSpec:
    """One quadrotor with the antennas moved to the scenario's lever arms, without its keyframe,
    its rotors transmitted by `rotors` ("site" as in the file, or "joint": _rotors_through_joint).

    The model's `hover` keyframe describes one vehicle alone, not the scene: it is deleted here,
    before attaching (deleting the attached copies from the scene costs O(N) each).
    """
    q = mujoco.MjSpec.from_file(str(MODELS / "quadrotor.xml"))
    a, b = scenario.world.antenna_a, scenario.world.antenna_b
    tips = {1: (a, 0.0, 0.0), 2: (0.0, b, 0.0), 3: (0.0, -b, 0.0)}
    for k, tip in tips.items():
        q.site(f"ant{k}").pos = tip
        q.geom(f"antenna{k}").pos = tip
        start = np.array(q.geom(f"boom{k}").fromto[:3])
        q.geom(f"boom{k}").fromto = np.concatenate([start, tip])
    q.delete(q.key("hover"))
    if rotors == "joint":
        _rotors_through_joint(q)
    return q


def _rotors_through_joint(q: mujoco.MjSpec) -> None:
    """Rotor actuators transmitted through the vehicle's free joint (the joint route, docs/models.md).

    Each rotor's site transmission (force ctrl along body z at the rotor site, drag torque
    gear[5] ctrl about body z) becomes a joint transmission whose 6-D gear holds only the rotor's
    moment about the centre of mass, in the body frame (the free joint's rotational dofs):
    (0, 0, 0, r x e3 + gear[5] e3) with r the site position from the centre of mass (body frame,
    m). The thrust force itself (sum of ctrl along body z, world frame) cannot go through the free
    joint, whose translational gear acts in the world frame: testbed.sim.thrust adds it to
    xfrc_applied at every physics step. The rotor sites stay (the mixer and the viewer use them).
    """
    com = np.array(q.body("base").ipos)
    for k in range(1, 5):
        act = q.actuator(f"rotor{k}")
        moment = np.cross(np.array(q.site(f"rotor{k}").pos) - com, [0.0, 0.0, 1.0])
        moment[2] += act.gear[5]
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.target = "root"
        act.gear = np.concatenate([np.zeros(3), moment])


def _vehicle_spec(template: mujoco.MjSpec, number: int) -> mujoco.MjSpec:
    """Vehicle `number` (1-based): a copy of the template (14x cheaper than parsing the file),
    its frame coloured by number."""
    q = template.copy()
    q.material("frame").rgba = (*PALETTE[(number - 1) % len(PALETTE)], 1.0)
    return q


def _attach(parent: mujoco.MjSpec, child: mujoco.MjSpec, prefix: str) -> None:
    parent.attach(child, prefix=prefix, frame=parent.worldbody.add_frame())


def _vehicle_block(template: mujoco.MjSpec, n: int, a: int, k: int) -> mujoco.MjSpec:
    """Vehicles a 10^k .. (a + 1) 10^k - 1 (those <= n; k >= 1) in one spec, each named by its
    digits after those of `a` ("5/base" in block (1, 1) is vehicle 15's base). The block's own
    default class is renamed "L{k}", so that once prefixed ("uav1L1") it is unique in the scene.
    """
    block = mujoco.MjSpec()
    block.default.name = f"L{k}"
    for d in range(10):
        first = (10 * a + d) * 10 ** (k - 1)
        if first > n:
            break
        if k == 1:
            _attach(block, _vehicle_spec(template, first), f"{d}/")
        else:
            _attach(block, _vehicle_block(template, n, 10 * a + d, k - 1), str(d))
    return block


def _attach_vehicles(spec: mujoco.MjSpec, template: mujoco.MjSpec, n: int) -> None:
    """Attach vehicles 1..n to the scene, in this order, as uav1/, uav2/, ...

    MjSpec.attach costs time proportional to the number of named elements already in the parent
    (MuJoCo checks names), so attaching n vehicles one by one to the scene is O(n^2): 65 s of CPU
    for 1000 vehicles. Instead vehicles are grouped by their decimal digits: vehicles 10..19 are
    attached (as "0/".."9/") to a block spec which is attached once with prefix "uav1", blocks of
    such blocks hold 100..199, and so on. Every attach goes into a spec of at most ten children,
    O(n log n) in all (4 s for 1000 vehicles). The compiled model is the same as with one by one
    attaching (vehicles in numerical order; the blocks' frames are identities); the scene XML has
    the blocks' nested default classes.
    """
    for k in range(len(str(n))):  # vehicles with k + 1 digits
        for a in range(1, 10):
            if a * 10 ** k > n:
                break
            if k == 0:
                _attach(spec, _vehicle_spec(template, a), f"uav{a}/")
            else:
                _attach(spec, _vehicle_block(template, n, a, k), f"uav{a}")


ROUTE_NOTE = (
    "Rotor thrust route 'joint': each actuator uav{i}/rotor{k} (ctrl = thrust, N) acts through the free "
    "joint uav{i}/root with a gear holding only the rotor's moment about the centre of mass (body frame). "
    "The thrust force, the sum of the four ctrl along body z, is added by the testbed to xfrc_applied at "
    "every step (testbed/sim/thrust.py): in a plain viewer the rotors turn the vehicle but do not lift it. "
    "Sites uav{i}/rotor{k} mark the rotors. See docs/models.md."
)


def build(scenario: Scenario, rotors: str | None = None) -> "Physics":
    """Compile the scene of a scenario, placed at the reference's initial state (in flown mode
    with the flat attitude a quadrotor has on that path: a prescribed attitude such as eq. 31's
    cannot be held in flight and would start the run with a levelling transient).

    rotors: "site" or "joint" (see rotor_route, which chooses when None)."""
    rotors = rotors or rotor_route(scenario)
    if rotors not in ("site", "joint"):
        raise ValueError(f"rotors must be 'site' or 'joint', got {rotors!r}")
    spec = mujoco.MjSpec.from_file(str(MODELS / "arena.xml"))
    if rotors == "joint":  # the scene explains its route to whoever opens scene.xml
        spec.add_text(name="rotor_route", data=ROUTE_NOTE)
    w = scenario.world
    spec.option.timestep = w.timestep
    ref0 = evaluate(scenario.trajectory, 0.0, flat=scenario.motion == "flown")
    _attach_vehicles(spec, _vehicle_template(scenario, rotors), scenario.vehicles)
    for k, p in enumerate(w.anchors, start=1):
        spec.worldbody.add_site(name=f"anchor{k}", pos=p, size=[0.05, 0, 0], rgba=[1, 0.8, 0.1, 1], group=4)
        spec.worldbody.add_geom(
            name=f"anchor{k}_mast", type=mujoco.mjtGeom.mjGEOM_CYLINDER, pos=[p[0], p[1], p[2] / 2],
            size=[0.03, max(p[2] / 2, 0.01), 0], material="anchor", contype=0, conaffinity=0, group=2,
        )
    environment = spec.find_default("arena")  # group 0: drawn, colliding (models/arena.xml)
    for k, ob in enumerate(w.obstacles, start=1):
        gtype = mujoco.mjtGeom.mjGEOM_BOX if ob.type == "box" else mujoco.mjtGeom.mjGEOM_CYLINDER
        half = np.radians(ob.yaw_deg) / 2
        spec.worldbody.add_geom(environment, name=f"obstacle{k}", type=gtype, pos=ob.pos, size=ob.size, quat=[np.cos(half), 0, 0, np.sin(half)], material="obstacle")
    # Scene extent for the free camera and clipping planes (znear/zfar are in units of extent).
    pts = ref0.pos[0]
    extent = float(max(10.0, np.ptp(pts, axis=0).max(), *(np.abs(np.array(w.anchors)).max(axis=0) if w.anchors else [0])))
    spec.stat.extent = extent
    spec.stat.center = pts.mean(axis=0)
    spec.visual.map.znear = 0.02 / extent
    spec.visual.map.zfar = 50.0
    physics = Physics(spec, scenario.vehicles)
    physics.set_reference_state(ref0, 0)
    spec.add_key(name="start", qpos=physics.data.qpos.copy(), qvel=physics.data.qvel.copy())
    physics.recompile_keeping_state()
    return physics


def _rows(arr: np.ndarray, first: np.ndarray, width: int) -> np.ndarray:
    """View (M, width, ...) of rows first[i] .. first[i] + width - 1 of `arr` (along axis 0).

    first: (M,) start indices spaced by a constant stride >= width (vehicles are attached one
    after another, so their joints, bodies, actuators and sensors are); raises otherwise.
    """
    stride = int(first[1] - first[0]) if len(first) > 1 else width
    if stride < width or np.any(first != first[0] + stride * np.arange(len(first))):
        raise ValueError(f"rows starting at {first.tolist()} are not evenly spaced by >= {width}")
    view = arr[first[0] : first[0] + stride * len(first)].reshape(len(first), stride, *arr.shape[1:])
    return view[:, :width]


@dataclass(frozen=True, slots=True)
class StateViews:
    """Views (not copies) of every vehicle's state in one MjData, for per-tick loops.

    pos, vel: (N, 3) world, m and m/s (qpos, qvel); omega: (N, 3) body frame, rad/s (qvel);
    rotation: (N, 3, 3) body-to-world (xmat, valid after the position stage); ctrl: (N, 4) rotor
    thrusts rotor1..rotor4, N (writable); xfrc: (N, 6) the vehicle bodies' xfrc_applied, world
    force (N) and torque (N m) at the centre of mass (writable). Valid while that MjData lives.
    """

    pos: np.ndarray
    vel: np.ndarray
    omega: np.ndarray
    rotation: np.ndarray
    ctrl: np.ndarray
    xfrc: np.ndarray


@dataclass(frozen=True, slots=True)
class RayTargets:
    """Geoms a ray can hit (Physics.ray_targets) with their bounding boxes in the geom frame.

    ids, body: (G,) geom and body ids; plane: (G,) bool (planes have no box); centre, half: (G, 3)
    box centre and half-sizes (m, grown by SEGMENT_MARGIN; centre 0 for planes).
    """

    ids: np.ndarray
    plane: np.ndarray
    centre: np.ndarray
    half: np.ndarray
    body: np.ndarray


class Physics:
    """A compiled scene and its state, with named and vectorized accessors.

    Vehicles are numbered 1..N as in the papers and the site names (`uav{i}/ant1`); arrays over
    vehicles are indexed 0..N-1. World frame ENU, metres, seconds; quaternions wxyz.
    """

    def __init__(self, spec: mujoco.MjSpec, vehicles: int):
        self.spec = spec
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        self.n = vehicles
        self._cache_addresses()

    def recompile_keeping_state(self) -> None:
        qpos, qvel = self.data.qpos.copy(), self.data.qvel.copy()
        self.model = self.spec.compile()
        self.data = mujoco.MjData(self.model)
        self.data.qpos[:], self.data.qvel[:] = qpos, qvel
        mujoco.mj_forward(self.model, self.data)
        self._cache_addresses()

    def _cache_addresses(self) -> None:
        m = self.model
        joints = [m.joint(f"uav{i}/root") for i in range(1, self.n + 1)]
        self.qpos_adr = np.array([j.qposadr[0] for j in joints])
        self.dof_adr = np.array([j.dofadr[0] for j in joints])
        self._qpos_idx = self.qpos_adr[:, None] + np.arange(7)
        self._qvel_idx = self.dof_adr[:, None] + np.arange(6)
        self.body_ids = np.array([m.body(f"uav{i}/base").id for i in range(1, self.n + 1)])
        self.actuator_idx = np.array([[m.actuator(f"uav{i}/rotor{k}").id for k in range(1, 5)] for i in range(1, self.n + 1)])
        self.rotor_site_idx = np.array([[m.site(f"uav{i}/rotor{k}").id for k in range(1, 5)] for i in range(1, self.n + 1)])
        self.rotor_route = "joint" if m.actuator_trntype[self.actuator_idx[0, 0]] == mujoco.mjtTrn.mjTRN_JOINT else "site"
        acc = [m.sensor(f"uav{i}/accelerometer") for i in range(1, self.n + 1)]
        gyr = [m.sensor(f"uav{i}/gyro") for i in range(1, self.n + 1)]
        self._acc_idx = np.array([s.adr[0] for s in acc])[:, None] + np.arange(3)
        self._gyro_idx = np.array([s.adr[0] for s in gyr])[:, None] + np.arange(3)
        self.imu_idx = np.concatenate([self._acc_idx, self._gyro_idx], axis=1)  # (N, 6) into sensordata
        self._site_ids: dict[str, int] = {}
        for key in ("vehicle_mass", "vehicle_inertia", "_geom_vehicle", "_geom_obstacle"):
            self.__dict__.pop(key, None)

    # ------------------------------------------------------------------ names and sites
    @property
    def time(self) -> float:
        return float(self.data.time)

    def site_id(self, name: str) -> int:
        """MuJoCo id of a site by its full name (e.g. 'uav2/uwb', 'anchor3')."""
        if name not in self._site_ids:
            sid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, name)
            if sid < 0:
                raise KeyError(f"no site named {name!r} in the scene")
            self._site_ids[name] = sid
        return self._site_ids[name]

    def site_ids(self, names: list[str]) -> np.ndarray:
        return np.array([self.site_id(n) for n in names], dtype=int)

    def site_pos(self, name: str | np.ndarray) -> np.ndarray:
        """Site position(s), world frame, m: (3,) for a name, (M, 3) for an id array."""
        ids = self.site_id(name) if isinstance(name, str) else name
        return self.data.site_xpos[ids].copy()

    def site_xmat(self, name: str | np.ndarray) -> np.ndarray:
        """Site orientation(s) as rotation matrices site-to-world: (3, 3) or (M, 3, 3)."""
        ids = self.site_id(name) if isinstance(name, str) else name
        return self.data.site_xmat[ids].reshape(*np.shape(ids), 3, 3).copy()

    def site_vel(self, name: str | np.ndarray) -> np.ndarray:
        """Site linear velocity(ies), world frame, m/s: (3,) or (M, 3). Needs mj_forward's velocity stage."""
        ids = [self.site_id(name)] if isinstance(name, str) else list(np.atleast_1d(name))
        out = np.empty((len(ids), 3))
        res = np.empty(6)
        for k, sid in enumerate(ids):
            mujoco.mj_objectVelocity(self.model, self.data, mujoco.mjtObj.mjOBJ_SITE, int(sid), res, 0)
            out[k] = res[3:]
        return out[0] if isinstance(name, str) else out

    def site_vels(self, ids: np.ndarray) -> np.ndarray:
        """Linear velocities of sites `ids` (M,), world frame, m/s: (M, 3), vectorized.

        Same quantity as `site_vel` (mj_objectVelocity): the body's com-based velocity cvel
        (valid after the velocity stage) moved from the root's subtree centre of mass to the site.
        """
        m, d = self.model, self.data
        ids = np.asarray(ids, dtype=int)
        body = m.site_bodyid[ids]
        cvel = d.cvel[body]
        arm = d.site_xpos[ids] - d.subtree_com[m.body_rootid[body]]
        return cvel[:, 3:] + np.cross(cvel[:, :3], arm)

    def site_body(self, ids: np.ndarray) -> np.ndarray:
        """Body ids (M,) of sites `ids` (M,)."""
        return self.model.site_bodyid[np.asarray(ids, dtype=int)].copy()

    def ray(self, start: np.ndarray, end: np.ndarray, geomgroup: np.ndarray | None, bodyexclude: int = -1) -> tuple[float, int]:
        """First geom hit on the segment start -> end (world, m), as in mj_ray.

        Returns (distance from start in m, geom id), or (inf, -1) if nothing is hit before `end`.
        geomgroup: (6,) uint8 mask of geom groups that can block (None: all); bodyexclude: a
        body whose geoms are ignored (-1: none).
        """
        vec = np.asarray(end, float) - np.asarray(start, float)
        length = float(np.linalg.norm(vec))
        gid = np.array([-1], dtype=np.int32)
        dist = mujoco.mj_ray(self.model, self.data, np.asarray(start, float), vec / length, geomgroup, 1, int(bodyexclude), gid)
        if dist < 0 or dist > length:
            return np.inf, -1
        return float(dist), int(gid[0])

    def rays_from(self, start: np.ndarray, ends: np.ndarray, geomgroup: np.ndarray | None, bodyexclude: int = -1) -> tuple[np.ndarray, np.ndarray]:
        """First hits of segments from one point to many (mj_multiRay): ends (M, 3) world, m.

        Returns distances (M,) from start (inf where nothing is hit before the end) and geom ids
        (M,) (-1 where nothing is hit).
        """
        ends = np.asarray(ends, float)
        return self.rays(np.asarray(start, float)[None], np.zeros(len(ends), dtype=int), ends, geomgroup, np.array([bodyexclude]))

    def rays(self, origins: np.ndarray, source: np.ndarray, ends: np.ndarray, geomgroup: np.ndarray | None, bodyexclude: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First hits of segments origins[source[l]] -> ends[l], one mj_multiRay per origin used.

        origins: (S, 3) world, m; source: (M,) indices into origins; ends: (M, 3) world, m;
        bodyexclude: (S,) body whose geoms are ignored by the rays of each origin (-1: none).
        Returns distances (M,) from the origin (inf where nothing is hit before the end) and geom
        ids (M,) (-1 where nothing is hit).
        """
        order = np.argsort(source, kind="stable")  # rays of one origin contiguous
        src = source[order]
        vec = ends[order] - origins[src]
        length = np.linalg.norm(vec, axis=1)
        unit = vec / length[:, None]
        gid = np.full(len(unit), -1, dtype=np.int32)
        dist = np.full(len(unit), -1.0)
        edges = [0, *(np.flatnonzero(np.diff(src)) + 1).tolist(), len(src)] if len(src) else [0]
        for a, b in zip(edges[:-1], edges[1:]):  # rays src[a:b] share their origin
            s = src[a]
            mujoco.mj_multiRay(self.model, self.data, origins[s], unit[a:b].reshape(-1), geomgroup, 1, int(bodyexclude[s]),
                               gid[a:b], dist[a:b], None, b - a, float(length[a:b].max()) + 1.0)
        miss = (dist < 0) | (dist > length)
        dist[miss] = np.inf
        gid[miss] = -1
        out_dist, out_gid = np.empty_like(dist), np.empty_like(gid)
        out_dist[order], out_gid[order] = dist, gid
        return out_dist, out_gid

    def ray_targets(self, geomgroup: np.ndarray) -> RayTargets:
        """The geoms mj_ray / mj_multiRay can hit with group mask geomgroup (6,): those in an
        enabled group (clamped to 0..5) that are visible (MuJoCo's rays skip geoms whose rgba, or
        material rgba, has alpha 0, such as the vehicles' collision boxes)."""
        m = self.model
        alpha = np.where(m.geom_matid >= 0, m.mat_rgba[m.geom_matid, 3], m.geom_rgba[:, 3])
        ids = np.flatnonzero((alpha != 0) & (np.asarray(geomgroup)[np.clip(m.geom_group, 0, 5)] != 0))
        plane = m.geom_type[ids] == mujoco.mjtGeom.mjGEOM_PLANE
        centre = np.where(plane[:, None], 0.0, m.geom_aabb[ids, :3])
        return RayTargets(ids, plane, centre, m.geom_aabb[ids, 3:] + SEGMENT_MARGIN, m.geom_bodyid[ids].copy())

    def segments_may_hit(self, targets: RayTargets, start: np.ndarray, end: np.ndarray, ignore: np.ndarray) -> np.ndarray:
        """(L,) bool: whether segment l from start[l] to end[l] ((L, 3) world, m) may touch one of
        the target geoms other than those on bodies ignore[l] ((L, k) body ids, -1 for none).

        Conservative (never False where a ray along the segment hits such a geom): a plane only
        when an end point lies within SEGMENT_MARGIN above it or below; any other geom when the
        segment meets its bounding box (geom_aabb, geom frame) grown by SEGMENT_MARGIN, by the
        separating-axis test of a segment and a box (three box axes, three cross products). The
        test runs only on the (segment, box) pairs whose bounding spheres meet, found with a k-d
        tree of the box centres: cost O((G + L) log G + pairs), not O(G L).
        """
        d = self.data
        start, end = np.asarray(start, float), np.asarray(end, float)
        hit = np.zeros(len(start), dtype=bool)
        if len(start) == 0:  # no link sampled at this instant (all lost, or out of range)
            return hit
        ignore = np.asarray(ignore).reshape(len(start), -1)
        mid, half = 0.5 * (start + end), 0.5 * (end - start)
        for g in np.flatnonzero(targets.plane):  # planes: local z up
            Rt = d.geom_xmat[targets.ids[g]].reshape(3, 3).T
            z = Rt[2] @ (mid - d.geom_xpos[targets.ids[g]]).T
            touch = z - np.abs(Rt[2] @ half.T) <= SEGMENT_MARGIN
            hit |= touch & (ignore != targets.body[g]).all(axis=1)
        box = np.flatnonzero(~targets.plane)
        if len(box) == 0:
            return hit
        ids = targets.ids[box]
        R = d.geom_xmat[ids].reshape(-1, 3, 3)
        centre = d.geom_xpos[ids] + (R @ targets.centre[box][:, :, None])[:, :, 0]  # (B, 3) world
        radius = np.linalg.norm(targets.half[box], axis=1)
        # candidate pairs: boxes up to twice the median size (airframes) from the k-d tree, the
        # few larger ones (obstacles) with every segment
        large = radius > 2 * np.median(radius)
        small = np.flatnonzero(~large)
        reach = np.linalg.norm(half, axis=1) + radius[small].max(initial=0.0) + SEGMENT_MARGIN
        near = cKDTree(centre[small]).query_ball_point(mid, reach) if len(small) else [[]] * len(start)
        counts = np.fromiter(map(len, near), dtype=int, count=len(near))
        link = np.concatenate([np.repeat(np.arange(len(start)), counts), np.repeat(np.arange(len(start)), large.sum())])
        if len(link) == 0:
            return hit
        geom = np.concatenate([small[np.concatenate(near).astype(int)] if counts.sum() else np.empty(0, dtype=int),
                               np.tile(np.flatnonzero(large), len(start))])
        keep = (targets.body[box][geom][:, None] != ignore[link]).all(axis=1)
        link, geom = link[keep], geom[keep]
        # world-to-geom rotations with rows x, y, z, x, y: components [1:4] and [2:5] of a rotated
        # vector are its cyclic shifts (for the cross products); midpoint and half-vector of the
        # segment in each geom's frame, from the box centre: (K, 5)
        Rt = R[geom].transpose(0, 2, 1)[:, [0, 1, 2, 0, 1]]
        m = (Rt @ (mid[link] - centre[geom])[:, :, None])[:, :, 0]
        e = (Rt @ half[link][:, :, None])[:, :, 0]
        ae = np.abs(e)
        h = targets.half[box][geom][:, [0, 1, 2, 0, 1]]
        apart = (np.abs(m[:, :3]) > h[:, :3] + ae[:, :3]).any(axis=1)
        cross = m[:, 1:4] * e[:, 2:5] - m[:, 2:5] * e[:, 1:4]
        apart |= (np.abs(cross) > h[:, 1:4] * ae[:, 2:5] + h[:, 2:5] * ae[:, 1:4]).any(axis=1)
        hit[link[~apart]] = True
        return hit

    # ---------------------------------------------------------------- vehicle states
    @property
    def pos(self) -> np.ndarray:
        """(N, 3) body origins (centre of mass), world, m."""
        return self.data.qpos[self._qpos_idx[:, :3]]

    @property
    def quat(self) -> np.ndarray:
        """(N, 4) body-to-world quaternions, wxyz."""
        return self.data.qpos[self._qpos_idx[:, 3:]]

    @property
    def vel(self) -> np.ndarray:
        """(N, 3) linear velocity of the body origins, world, m/s."""
        return self.data.qvel[self._qvel_idx[:, :3]]

    @property
    def omega(self) -> np.ndarray:
        """(N, 3) angular velocity, body frame, rad/s."""
        return self.data.qvel[self._qvel_idx[:, 3:]]

    @property
    def rotation(self) -> np.ndarray:
        """(N, 3, 3) body-to-world rotation matrices (valid after the position stage)."""
        return self.data.xmat[self.body_ids].reshape(-1, 3, 3)

    def views(self) -> StateViews:
        """Views of the vehicle states in the current `data` (see StateViews)."""
        d = self.data
        qpos, qvel = _rows(d.qpos, self.qpos_adr, 7), _rows(d.qvel, self.dof_adr, 6)
        first_rotor = self.actuator_idx[:, 0]
        if np.any(self.actuator_idx != first_rotor[:, None] + np.arange(4)):
            raise ValueError("rotor actuators of a vehicle are not consecutive")
        return StateViews(
            pos=qpos[:, :3], vel=qvel[:, :3], omega=qvel[:, 3:],
            rotation=_rows(d.xmat, self.body_ids, 1).reshape(-1, 3, 3), ctrl=_rows(d.ctrl, first_rotor, 4),
            xfrc=_rows(d.xfrc_applied, self.body_ids, 1)[:, 0],
        )

    @property
    def accelerometer(self) -> np.ndarray:
        """(N, 3) MuJoCo accelerometer: specific force in the imu site frame, m/s^2."""
        return self.data.sensordata[self._acc_idx]

    @property
    def gyro(self) -> np.ndarray:
        """(N, 3) MuJoCo gyro: angular velocity in the imu site frame, rad/s."""
        return self.data.sensordata[self._gyro_idx]

    @cached_property
    def vehicle_mass(self) -> float:
        """Mass of one vehicle, kg (all vehicles are alike)."""
        return float(self.model.body_subtreemass[self.body_ids[0]])

    @cached_property
    def vehicle_inertia(self) -> np.ndarray:
        """(3,) principal inertia of one vehicle about its body axes, kg m^2."""
        return self.model.body_inertia[self.body_ids[0]].copy()

    def set_reference_state(self, ref: RefState, k: int) -> None:
        """Kinematic playback: qpos, qvel and qacc of every vehicle from reference instant k.

        Then `mj_inverse` computes everything else at that instant: site poses and velocities and
        the accelerometer/gyro readings consistent with the reference motion.
        """
        d = self.data
        d.qpos[self._qpos_idx] = np.concatenate([ref.pos[k], ref.quat[k]], axis=1)
        d.qvel[self._qvel_idx] = np.concatenate([ref.vel[k], ref.omega[k]], axis=1)
        d.qacc[self._qvel_idx] = np.concatenate([ref.acc[k], ref.alpha[k]], axis=1)
        mujoco.mj_inverse(self.model, d)

    def contacts_at(self, qpos: np.ndarray) -> np.ndarray:
        """The contacts touching a vehicle in the state qpos (nq,) (positions only: kinematics and
        collision, mj_fwdPosition; the run's velocities are left alone).

        Returns (c, 2) int: (vehicle, other), 0-based vehicle index; other a vehicle index
        (vehicle < other), OBSTACLE for a `world.obstacles` geom, FLOOR for anything else of the
        world body (floor, masts). One row per MuJoCo contact (a box pair may touch at several
        points)."""
        m, d = self.model, self.data
        d.qpos[:] = qpos
        mujoco.mj_fwdPosition(m, d)
        c = d.contact[: d.ncon]
        if d.ncon == 0:
            return np.zeros((0, 2), np.int64)
        who, obstacle = self._geom_vehicle, self._geom_obstacle
        a, b = who[c.geom1], who[c.geom2]
        other_a = np.where(obstacle[c.geom1], OBSTACLE, FLOOR)
        other_b = np.where(obstacle[c.geom2], OBSTACLE, FLOOR)
        v = np.where(a >= 0, a, b)
        o = np.where((a >= 0) & (b >= 0), np.maximum(a, b), np.where(a >= 0, other_b, other_a))
        v = np.where((a >= 0) & (b >= 0), np.minimum(a, b), v)
        keep = (a >= 0) | (b >= 0)
        return np.stack([v[keep], o[keep]], axis=1).astype(np.int64)

    @cached_property
    def _geom_vehicle(self) -> np.ndarray:
        """(ngeom,) int: the vehicle index of each geom, -1 for the world's."""
        m = self.model
        veh = np.full(m.nbody, -1)
        veh[self.body_ids] = np.arange(self.n)
        return veh[m.body_rootid[m.geom_bodyid]]

    @cached_property
    def _geom_obstacle(self) -> np.ndarray:
        """(ngeom,) bool: the geom is one of `world.obstacles`."""
        m = self.model
        return np.array([(m.geom(g).name or "").startswith("obstacle") for g in range(m.ngeom)])

    def contact_forces_at(self, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """(N,) N: the normal contact force on each vehicle, summed over its contacts, in the state
        qpos (nq,), qvel (nv,) with the rotors and applied forces off (mj_forward: MuJoCo's soft
        contacts give the force of that penetration and approach speed)."""
        m, d = self.model, self.data
        d.qpos[:], d.qvel[:] = qpos, qvel
        d.ctrl[:] = 0.0
        d.xfrc_applied[:] = 0.0
        mujoco.mj_forward(m, d)
        out, f = np.zeros(self.n), np.zeros(6)
        who = self._geom_vehicle
        for i in range(d.ncon):
            mujoco.mj_contactForce(m, d, i, f)
            for v in {int(who[d.contact.geom1[i]]), int(who[d.contact.geom2[i]])} - {-1}:
                out[v] += abs(f[0])
        return out

    def warnings(self) -> dict[str, int]:
        """MuJoCo warnings raised so far, by name (empty if none)."""
        return {mujoco.mjtWarning(i).name: int(n) for i, n in enumerate(self.data.warning.number) if n}

    def to_xml(self) -> str:
        """The exact model simulated, loadable with mujoco.MjModel.from_xml_string."""
        return self.spec.to_xml()


def lever_arms(physics: Physics) -> dict[str, tuple[str, np.ndarray]]:
    """{site: (vehicle body "uavI", lever arm (3,) m in that vehicle's base frame)} for every vehicle site,
    by forward kinematics at the model's reference pose (the vehicles are rigid, so a site's offset
    in its vehicle's base frame is constant): the Context's `sites` (testbed.plugins.context)."""
    m = physics.model
    d = mujoco.MjData(m)  # a scratch state: the run's own data is left alone
    mujoco.mj_kinematics(m, d)
    named: dict[str, list[tuple[int, str]]] = {}  # "uavI" -> its sites (id, name), each name read once
    for sid in range(m.nsite):
        name = m.site(sid).name
        head, sep, _ = name.partition("/")
        if sep:
            named.setdefault(head, []).append((sid, name))
    out = {}
    for i, bid in enumerate(physics.body_ids, start=1):
        R = d.xmat[bid].reshape(3, 3)
        for sid, name in named.get(f"uav{i}", ()):
            if m.body_rootid[m.site_bodyid[sid]] == m.body_rootid[bid]:
                arm = R.T @ (d.site_xpos[sid] - d.xpos[bid])
                arm.flags.writeable = False
                out[name] = (f"uav{i}", arm)
    return out
