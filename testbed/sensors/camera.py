"""Camera / VisNav stream `camera` (seed 004): the leader's `cam` sees the follower's LED beacons.

Frames. Camera frame C = the MuJoCo camera frame of "uav{leader}/cam": x right, y up, looking
along -z (for the MJCF tail camera: x_C = body y, y_C = body z, z_C = body x). A point p (world)
has p_C = R_C^T (p - c), depth = -z_C.

Focal-plane coordinates, eqs. 5-6 with C the world-to-camera rotation and f = focal_length:
  alpha = -f (C_1 . (p - c)) / (C_3 . (p - c)) = f x_C / depth,  beta = f y_C / depth
(alpha right, beta up on the focal plane). Unit line of sight (eqs. 9-10) in the camera frame:
  b = p_C / |p_C|  (b_z < 0 in front of the camera).

Visibility: depth > min_depth, inside the image (pixel centre of the projection within
[-0.5, W - 0.5] x [-0.5, H - 0.5]) and not occluded: mj_ray from the camera centre towards the LED
centre through the rendered geom groups 0-2 hits that LED's geom first (translucent geoms, rgba
alpha < 1 such as propeller disks, are seen through, as in the render).

Intrinsics from the MJCF camera: fy = (H / 2) / tan(fovy / 2), fx = fy (square pixels),
principal point at the image centre; pixel coordinates with (0, 0) the centre of the top-left
pixel: u = (W - 1)/2 + fx x_C / depth, v = (H - 1)/2 - fy y_C / depth.

Geometric path noise: (alpha, beta)/f gets eq. 8 noise,
  R_FOCAL = sigma^2 / (1 + d(a^2 + b^2)) [[(1 + d a^2)^2, (d a b)^2], [(d a b)^2, (1 + d b^2)^2]]
(a = alpha/f, b = beta/f, as printed in the paper); b gets the QUEST noise of eq. 13,
v = sigma (I - b b^T) n (covariance sigma^2 (I - b b^T)), reported normalised (b + v)/|b + v|.
Glint: with probability glint_prob a measurement's noise std is glint_factor x larger (one flag
for both forms). The same number of draws is made at every frame (4 LEDs).

Pixel path: the leader's camera is rendered offscreen (mujoco.Renderer, skybox off: a
band-pass-filtered beacon camera sees emitters, not sky). LED identity is solved by coding: the
follower's LED k is drawn in code colour CODES[k-1] (red, green, blue, magenta; set in the visual
scene only, the model is untouched), like VisNav's individually modulated beacons. For each code
a contrast image w = min(code-on channels) - max(code-off channels) is thresholded (w >= 30),
connected components that contain a saturated core pixel (code-on channels >= 200, code-off
channels <= 40: an emitter, not a lit coloured surface) are kept, the strongest is the LED,
its centroid is the w-weighted mean pixel. Centroids become alpha, beta and b through the
intrinsics; no noise is added (the rendering and detection error is the error).

Log: camera/value, camera/clean (M, 5) = [alpha, beta (focal-plane, units of f), b_x, b_y, b_z
(camera frame)]; camera/pixel, camera/pixel_clean (M, 2) = [u, v] px; camera/glint (M,) bool;
camera/led (M,) 1-based LED number; src = "uav{leader}/cam", dst = "uav{follower}/led{k}".
"""
from __future__ import annotations

import cv2
import mujoco
import numpy as np

from testbed.sensors.base import Recorder, common_keys
from testbed.sensors.config import CameraConfig
from testbed.sim.world import Physics

N_LEDS = 4
CODES = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 0], [0, 1, 1]], dtype=bool)
RENDER_GROUPS = np.array([1, 1, 1, 0, 0, 0], dtype=np.uint8)  # what mujoco.Renderer draws by default
LOOSE = 30  # contrast w (0..255) of the pixels that enter a blob and its centroid
CORE_ON, CORE_OFF = 200, 40  # a saturated core pixel: code-on channels >= 200, code-off <= 40


class Intrinsics:
    """Pinhole intrinsics of a MuJoCo camera: width, height (px), fx = fy (px), cx, cy (px)."""

    def __init__(self, model: mujoco.MjModel, cam_id: int):
        self.width, self.height = (int(x) for x in model.cam_resolution[cam_id])
        self.fy = self.height / 2 / np.tan(np.radians(model.cam_fovy[cam_id]) / 2)
        self.fx = self.fy
        self.cx, self.cy = (self.width - 1) / 2, (self.height - 1) / 2

    def project(self, xn: np.ndarray, yn: np.ndarray) -> np.ndarray:
        """Normalised coordinates x_C/depth, y_C/depth -> pixels (M, 2)."""
        return np.stack([self.cx + self.fx * xn, self.cy - self.fy * yn], axis=-1)

    def normalised(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (uv[..., 0] - self.cx) / self.fx, -(uv[..., 1] - self.cy) / self.fy


def led_geometry(physics: Physics, cam_id: int, led_sites: np.ndarray, led_geoms: np.ndarray, intr: Intrinsics, min_depth: float) -> dict[str, np.ndarray]:
    """Geometric projection of the LED centres from the current physics state.

    Returns xn, yn (K,) normalised coordinates, b (K, 3) unit LOS (camera frame), uv (K, 2) px,
    visible (K,) bool (in front, in the image, not occluded).
    """
    d = physics.data
    c = d.cam_xpos[cam_id].copy()
    R = d.cam_xmat[cam_id].reshape(3, 3)
    P = d.site_xpos[led_sites]
    pc = (P - c) @ R  # rows R^T (p - c)
    depth = -pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        xn, yn = pc[:, 0] / depth, pc[:, 1] / depth
    uv = intr.project(xn, yn)
    front = depth > min_depth
    inside = front & (uv[:, 0] >= -0.5) & (uv[:, 0] <= intr.width - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= intr.height - 0.5)
    visible = inside.copy()
    for k in np.flatnonzero(inside):
        visible[k] = _first_opaque_hit(physics, c, P[k]) == led_geoms[k]
    b = pc / np.linalg.norm(pc, axis=1, keepdims=True)
    return {"xn": xn, "yn": yn, "b": b, "uv": uv, "visible": visible}


def _geom_alpha(m: mujoco.MjModel, g: int) -> float:
    mat = m.geom_matid[g]
    return float(m.mat_rgba[mat][3]) if mat >= 0 else float(m.geom_rgba[g][3])


def _first_opaque_hit(physics: Physics, start: np.ndarray, end: np.ndarray, max_pass: int = 16) -> int:
    """Geom id of the first opaque geom on start -> end (rendered groups), -1 if none.

    A translucent geom is stepped through: the next cast starts just inside it and returns its
    exit surface, the one after continues beyond it.
    """
    p = np.asarray(start, float)
    direction = (end - p) / np.linalg.norm(end - p)
    for _ in range(max_pass):
        dist, gid = physics.ray(p, end, RENDER_GROUPS)
        if gid < 0 or _geom_alpha(physics.model, gid) >= 1.0:
            return gid
        p = p + direction * (dist + 1e-4)
    return -1


def detect_leds(img: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Centroids (n, 2) px of code-coloured LEDs 1..n in an RGB image (H, W, 3) uint8.

    Returns uv (n, 2) and found (n,) bool. See the module docstring for the method.
    """
    im = img.astype(np.int16)
    uv = np.full((n, 2), np.nan)
    found = np.zeros(n, dtype=bool)
    for k in range(n):
        on, off = CODES[k], ~CODES[k]
        w = im[..., on].min(axis=-1) - im[..., off].max(axis=-1)
        np.clip(w, 0, None, out=w)
        loose = (w >= LOOSE).astype(np.uint8)
        if not loose.any():
            continue
        count, labels, stats, _ = cv2.connectedComponentsWithStats(loose, connectivity=8)
        core = (im[..., on].min(axis=-1) >= CORE_ON) & (im[..., off].max(axis=-1) <= CORE_OFF)
        best, best_mass = -1, 0.0
        for lab in range(1, count):
            x0, y0, ww, hh = stats[lab, :4]
            sub_l = labels[y0 : y0 + hh, x0 : x0 + ww] == lab
            sub_w = w[y0 : y0 + hh, x0 : x0 + ww] * sub_l
            if not (core[y0 : y0 + hh, x0 : x0 + ww] & sub_l).any():
                continue
            mass = float(sub_w.sum())
            if mass > best_mass:
                best, best_mass = lab, mass
        if best < 0:
            continue
        x0, y0, ww, hh = stats[best, :4]
        sub_w = (w[y0 : y0 + hh, x0 : x0 + ww] * (labels[y0 : y0 + hh, x0 : x0 + ww] == best)).astype(float)
        ys, xs = np.mgrid[y0 : y0 + hh, x0 : x0 + ww]
        uv[k] = [(sub_w * xs).sum() / best_mass, (sub_w * ys).sum() / best_mass]
        found[k] = True
    return uv, found


class Camera:
    name = "camera"

    def __init__(self, cfg: CameraConfig, physics: Physics, rng: np.random.Generator, period_ticks: int):
        self.cfg, self.rng, self.period_ticks = cfg, rng, period_ticks
        m = physics.model
        self.cam_name = f"uav{cfg.leader}/cam"
        self.cam_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, self.cam_name)
        self.intr = Intrinsics(m, self.cam_id)
        f = cfg.follower
        self.led_sites = physics.site_ids([f"uav{f}/led{k}" for k in range(1, N_LEDS + 1)])
        self.led_geoms = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"uav{f}/led{k}_geom") for k in range(1, N_LEDS + 1)])
        self.dst_names = np.array([f"uav{f}/led{k}" for k in range(1, N_LEDS + 1)])
        self.src_name = f"uav{cfg.leader}/cam"
        self.renderer: mujoco.Renderer | None = None
        self.rec = Recorder("camera", {**common_keys(5), "pixel": ((2,), "f8"), "pixel_clean": ((2,), "f8"), "glint": ((), "?"), "led": ((), "i8")})

    # ------------------------------------------------------------------ pixel path
    def render(self, physics: Physics) -> np.ndarray:
        """RGB image (H, W, 3) uint8 of the leader's camera with the follower's LEDs code-coloured."""
        if self.renderer is None:
            self.renderer = mujoco.Renderer(physics.model, self.intr.height, self.intr.width)
        r = self.renderer
        r.update_scene(physics.data, camera=self.cam_name)
        r.scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = 0
        codes = {int(g): k for k, g in enumerate(self.led_geoms)}
        for j in range(r.scene.ngeom):
            g = r.scene.geoms[j]
            if g.objtype == mujoco.mjtObj.mjOBJ_GEOM and int(g.objid) in codes:
                g.rgba[:3] = CODES[codes[int(g.objid)]]
                g.rgba[3] = 1.0
        return r.render()

    def sample(self, physics: Physics, t: float, state_index: int) -> None:
        cfg, f = self.cfg, self.cfg.focal_length
        geo = led_geometry(physics, self.cam_id, self.led_sites, self.led_geoms, self.intr, cfg.min_depth)
        e2 = self.rng.standard_normal((N_LEDS, 2))
        e3 = self.rng.standard_normal((N_LEDS, 3))
        glint = self.rng.random(N_LEDS) < cfg.glint_prob
        a, bb, b = geo["xn"], geo["yn"], geo["b"]
        clean = np.column_stack([f * a, f * bb, b])
        if cfg.mode == "geometric":
            rows = np.flatnonzero(geo["visible"])
            s = cfg.sigma * np.where(glint, cfg.glint_factor, 1.0)
            # eq. 8 covariance (normalised focal-plane units), sampled through its Cholesky factor
            dd = cfg.d
            scale = 1.0 / (1.0 + dd * (a**2 + bb**2))
            R = np.empty((N_LEDS, 2, 2))
            R[:, 0, 0] = scale * (1 + dd * a**2) ** 2
            R[:, 1, 1] = scale * (1 + dd * bb**2) ** 2
            R[:, 0, 1] = R[:, 1, 0] = scale * (dd * a * bb) ** 2
            ab_noise = np.zeros((N_LEDS, 2))
            for k in rows:
                ab_noise[k] = np.linalg.cholesky(R[k]) @ e2[k] * s[k]
            # eq. 13: v = sigma (I - b b^T) n
            v = s[:, None] * (e3 - np.einsum("ki,ki->k", b, e3)[:, None] * b)
            bn = b + v
            bn /= np.linalg.norm(bn, axis=1, keepdims=True)
            an, bet = a + ab_noise[:, 0], bb + ab_noise[:, 1]
            value = np.column_stack([f * an, f * bet, bn])
            pixel = self.intr.project(an, bet)
        else:
            uv, found = detect_leds(self.render(physics), N_LEDS)
            rows = np.flatnonzero(found)
            xn, yn = self.intr.normalised(uv)
            bd = np.column_stack([xn, yn, -np.ones(N_LEDS)])
            bd /= np.linalg.norm(bd, axis=1, keepdims=True)
            value = np.column_stack([f * xn, f * yn, bd])
            pixel = uv
            glint = np.zeros(N_LEDS, dtype=bool)
        M = len(rows)
        self.rec.add(
            time=np.full(M, t), arrival=np.full(M, t + cfg.latency), state_index=np.full(M, state_index),
            value=value[rows], clean=clean[rows], src=np.full(M, self.src_name), dst=self.dst_names[rows],
            pixel=pixel[rows], pixel_clean=geo["uv"][rows], glint=glint[rows], led=rows + 1,
        )

    def arrays(self) -> dict[str, np.ndarray]:
        if self.renderer is not None:
            self.renderer.close()
            self.renderer = None
        return self.rec.arrays()
