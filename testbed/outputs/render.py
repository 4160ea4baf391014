"""Headless video and still images of a run directory, rendered offscreen with MuJoCo.

`render_run(run_dir)` replays the logged `qpos` of `run_dir/log.npz` in the exact model of
`run_dir/scene.xml` and writes `run_dir/video.mp4` (H.264, yuv420p); `save_frame(run_dir, t, path)`
writes one PNG of the same view. Nothing is simulated again: every frame is the logged state at
that instant (geodesic interpolation between the two nearest log rows), then `mj_forward`.

What a frame shows
- A tracking camera (a free `mjvCamera`) that keeps every vehicle, and every UWB anchor the swarm
  ranges to, in view: its lookat follows the middle of them and its distance is the smallest that
  keeps them all inside the picture with a margin (from their offsets in camera axes), both smoothed offline with
  a zero-phase Gaussian (no lag, no jitter; the distance is smoothed as an upper envelope so
  nobody leaves the picture when the swarm spreads). See `camera_track`. The
  viewing direction is fixed for the whole run: azimuth perpendicular to the direction of the
  largest horizontal spread (so a line or a leader-follower pair is seen side by side, not one
  behind the other), elevation 20-45 degrees down, steeper when the formation is spread in both
  horizontal directions (a cross, a box) so its plan is readable. With an isotropic layout the
  camera looks north (east to the right of the picture, as on a map).
- Markers: quadrotors are ~2 m across while scenes span up to 1.5 km, so a vehicle that would
  less than about 2 x `marker_px` pixels across gets a sphere of constant on-screen radius
  `marker_px` in its frame colour (a decoration added to the mjvScene, so obstacles still hide
  it) and a thin drop line to the ground (altitude cue); every vehicle leaves a fading trail of
  its recent path (constant-pixel-width lines) and has its number written next to it. Up close
  the real airframe is shown. No model geometry is changed.
- Picture-in-picture: the view of camera `uav{i}/cam` (640 x 480 on board, rendered smaller
  with the same 4:3 aspect and field of view) in the top-right corner with a thin border,
  for the leader of seed 004 by default.
- A text overlay (scenario name, simulated time, playback speed) drawn with OpenCV.
- Obstacles translucent (OBSTACLE_ALPHA), UWB anchors as yellow diamonds of constant size, and
  from the run directory (testbed.outputs.render_overlay): each vehicle's reference path from 3 s before
  to 10 s after the frame's time (white, REFERENCE_SPAN); the UWB links of the latest sample (LOS
  blue, NLOS orange), thinned by the option `links` (default: each vehicle's 2 shortest,
  `nearest_links`); the estimate (of the estimator flown on, else the first
  of estimates.npz) as a magenta segment from the true vehicle along the estimate's error (at the
  estimate's own time, render_overlay) and the 3-sigma ellipse of its horizontal covariance about
  its end (`error_drawing`), both `error_scale` times their size: to scale (1) unless that would
  draw them below a few pixels, as at the phase scenario's centimetres seen from hundreds of
  metres; then magnified by a round factor the legend states (`auto_error_scale`); vehicle
  numbers green with a GNSS fix and red without.
- A legend of what the frame shows (bottom right, see-through, under the anchors, estimates and
  numbers) and a scale bar (bottom left: a round length at the depth of the camera's lookat, the
  middle of the swarm).

Backend. MuJoCo chooses its OpenGL backend from `MUJOCO_GL` when it is first imported
(the command line sets `egl` unless the user chose, testbed/environment.py). If the renderer cannot be created in
this process, the backends egl and osmesa are probed each in a fresh subprocess; the first that
works renders the job in a subprocess (`python -m testbed.outputs.render ...` with that `MUJOCO_GL`).
If none works, `RenderError` says which system libraries to install.

Speed on software OpenGL (llvmpipe): the cost is per pixel, so resolution, multisampling
(`samples`, model.vis.quality.offsamples) and shadows (`shadow_size`, model.vis.quality.
shadowsize; 0 turns shadows off) are options; `max_seconds` caps the video length. The arena's
sun casts no shadow (models/arena.xml, castshadow="false") and the headlight never does, so with
the shipped arena the shadow size costs nothing; multisampling roughly halves the frame rate.
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import imageio.v2 as imageio
import numpy as np
from scipy.ndimage import gaussian_filter1d, maximum_filter1d
from tqdm import tqdm

from testbed.environment import last_line, stderr_to, written
from testbed.errors import RunError, TestbedError
from testbed.outdir import new_file
from testbed.outputs.render_overlay import LOS_RGBA, NLOS_RGBA, Overlays
from testbed.worker_process import worker_init

from testbed.errors import UsageError

INSTALL_HINT = (
    "install the EGL libraries (Debian/Ubuntu: apt-get install libegl1 libopengl0 libgl1-mesa-dri) "
    "or OSMesa (apt-get install libosmesa6), then run again; MUJOCO_GL=egl|osmesa chooses the backend"
)
BACKENDS = ("egl", "osmesa")
OBSTACLE_ALPHA = 0.45  # opacity of world.obstacles in a video (their material "obstacle")
FOVY_TRACK = 45.0  # deg, vertical field of view of the tracking camera (MuJoCo's free-camera default)
LINKS = ("nearest", "epoch", "none")  # which UWB links a frame draws (render_run, `links`)
REFERENCE_RGB = (235, 235, 235)  # reference paths (drawn on the picture)
ESTIMATE_RGB = (255, 60, 255)  # error segment and covariance ellipse (RGB, drawn on the picture)
ERROR_PX = 0.03  # auto_error_scale: the typical error drawing spans at least this fraction of the picture's height
ANCHOR_RGB = (255, 205, 25)  # UWB anchors (as their sites in models: yellow)
REFERENCE_SPAN = (3.0, 10.0)  # s of each vehicle's reference path drawn before and after the frame's time


def _mujoco():
    """MuJoCo, imported on first use (lazy on purpose): it fixes its OpenGL backend from MUJOCO_GL
    when first imported, and this module may choose the backend before that (module docstring)."""
    import mujoco

    return mujoco


class RenderError(TestbedError):
    """Rendering is impossible here (no OpenGL backend) or the run directory cannot be rendered:
    one line and exit code 2 on the command line."""


# ------------------------------------------------------------------------------ backend choice

_IN_PROCESS: tuple[bool, str] | None = None  # (works, error) for this process's MUJOCO_GL


def _probe_in_process() -> tuple[bool, str]:
    """Can this process create a MuJoCo offscreen renderer? (cached; error text if not)."""
    global _IN_PROCESS
    if _IN_PROCESS is None:
        try:
            mujoco = _mujoco()

            with mujoco.Renderer(mujoco.MjModel.from_xml_string("<mujoco/>"), 16, 16) as r:
                r.render()
            _IN_PROCESS = (True, "")
        except Exception as e:  # any import or GL failure means: not here
            _IN_PROCESS = (False, f"{type(e).__name__}: {e}")
    return _IN_PROCESS


def _probe_subprocess(backend: str) -> tuple[bool, str]:
    """Does `MUJOCO_GL=backend` give a working offscreen renderer in a fresh interpreter?"""
    code = (
        "import mujoco\n"
        "with mujoco.Renderer(mujoco.MjModel.from_xml_string('<mujoco/>'), 16, 16) as r: r.render()\n"
    )
    env = {**os.environ, "MUJOCO_GL": backend}
    env.pop("PYOPENGL_PLATFORM", None)  # mujoco sets it to match MUJOCO_GL
    try:
        p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    except (OSError, subprocess.TimeoutExpired) as e:
        return False, str(e)
    err = p.stderr.strip().splitlines()
    return p.returncode == 0, (err[-1] if err else f"exit code {p.returncode}")


def choose_backend() -> str | None:
    """None if this process can render; else the MUJOCO_GL value a subprocess must use.

    Raises RenderError naming the libraries to install when no backend works.
    """
    ok, err = _probe_in_process()
    if ok:
        return None
    current = os.environ.get("MUJOCO_GL", "")
    errors = [f"MUJOCO_GL={current or '(unset)'} in this process: {err}"]
    for backend in BACKENDS:
        if backend == current:
            continue
        ok, err = _probe_subprocess(backend)
        if ok:
            return backend
        errors.append(f"MUJOCO_GL={backend}: {err}")
    raise RenderError("no OpenGL backend for offscreen rendering works (" + "; ".join(errors) + "): " + INSTALL_HINT)


def _delegate(backend: str, call: dict) -> Path:
    """Run one render call in a subprocess with MUJOCO_GL=backend; returns the written path."""
    env = {**os.environ, "MUJOCO_GL": backend}
    env.pop("PYOPENGL_PLATFORM", None)
    p = subprocess.Popen([sys.executable, "-m", "testbed.outputs.render", "--call", json.dumps(call)], env=env, stdout=subprocess.PIPE, text=True)
    try:
        stdout, _ = p.communicate()
    finally:  # interrupted: SIGTERM lets the child remove its partial file
        if p.poll() is None:
            p.terminate()
            p.wait()
    if p.returncode != 0:
        raise RenderError(f"rendering with MUJOCO_GL={backend} in a subprocess failed (exit code {p.returncode})")
    return Path(stdout.strip().splitlines()[-1])


# --------------------------------------------------------------------------------- the replay


class _Replay:
    """The model of a run directory and its logged states, with interpolation in time.

    time: (K,) s; qpos: (K, nq). Vehicles are the bodies `uav{i}/base`, i = 1..N.
    """

    def __init__(self, run_dir: Path):
        mujoco = _mujoco()

        run_dir = Path(run_dir)
        for name in ("scene.xml", "log.npz"):
            if not (run_dir / name).is_file():
                raise RenderError(f"{run_dir}: not a run directory (no {name})")
        try:
            self.model = mujoco.MjModel.from_xml_path(str(run_dir / "scene.xml"))
        except ValueError as e:  # MuJoCo's XML and compile errors
            raise RenderError(f"{run_dir / 'scene.xml'}: not a readable MuJoCo model: {_one_line(e)}") from None
        self.data = mujoco.MjData(self.model)
        try:
            with np.load(run_dir / "log.npz", allow_pickle=False) as z:
                self.time = np.asarray(z["time"], float)
                self.qpos = np.asarray(z["qpos"], float)
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as e:
            raise RenderError(f"{run_dir / 'log.npz'}: not a readable run log (time and qpos arrays): {_one_line(e)}") from None
        if self.qpos.shape != (self.time.size, self.model.nq) or self.time.size == 0:
            raise RenderError(f"{run_dir}: log.npz qpos {self.qpos.shape} does not match time ({self.time.size},) and scene nq={self.model.nq}")
        ids = []
        while (b := mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, f"uav{len(ids) + 1}/base")) >= 0:
            ids.append(b)
        if not ids:
            raise RenderError(f"{run_dir}: scene.xml has no vehicle body uav1/base")
        self.body_ids = np.array(ids)
        self.n = len(ids)
        anchors = []
        while (a := mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, f"anchor{len(anchors) + 1}")) >= 0:
            anchors.append(a)
        self.anchor_ids = np.array(anchors, int)
        vehicle_of_body = np.full(self.model.nbody, -1)
        vehicle_of_body[self.body_ids] = np.arange(self.n)
        self.site_vehicle = vehicle_of_body[self.model.body_rootid[self.model.site_bodyid]]  # (nsite,) 0-based, -1: none
        self.colors = np.array([self._vehicle_rgba(i) for i in range(1, self.n + 1)], np.float32)
        self.meta = _read_meta(run_dir)
        self._v = np.zeros(self.model.nv)
        self.overlays = Overlays(run_dir, lambda name: mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, name), self.n)
        mid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_MATERIAL, "obstacle")
        if mid >= 0:  # obstacles translucent: vehicles behind a building or under a roof stay in view
            self.model.mat_rgba[mid, 3] = OBSTACLE_ALPHA

    def _vehicle_rgba(self, i: int) -> np.ndarray:
        """(4,) colour of vehicle i's frame material (the per-vehicle palette colour)."""
        mujoco = _mujoco()

        mid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_MATERIAL, f"uav{i}/frame")
        rgba = self.model.mat_rgba[mid].copy() if mid >= 0 else np.array([0.9, 0.2, 0.2, 1.0], np.float32)
        rgba[3] = 1.0
        return rgba

    def set_time(self, t: float, forward: bool = True) -> None:
        """Put the logged state at time t (s) into data: qpos between the two nearest rows.

        Between rows k and k+1 the state moves along the joint-space geodesic
        q(a) = q_k (+) a (q_{k+1} (-) q_k), a = (t - t_k) / (t_{k+1} - t_k), with MuJoCo's own
        mj_differentiatePos / mj_integratePos, so free-joint quaternions are slerped and stay
        unit. Outside the log the first or last row is held. Then mj_forward (or only
        mj_kinematics when forward is False).
        """
        mujoco = _mujoco()

        m, d = self.model, self.data
        k = int(np.clip(np.searchsorted(self.time, t, side="right") - 1, 0, self.time.size - 1))
        d.qpos[:] = self.qpos[k]
        if k + 1 < self.time.size and t > self.time[k]:
            dt = self.time[k + 1] - self.time[k]
            a = min(1.0, (t - self.time[k]) / dt) if dt > 0 else 0.0
            if a > 0:
                mujoco.mj_differentiatePos(m, self._v, 1.0, self.qpos[k], self.qpos[k + 1])
                mujoco.mj_integratePos(m, d.qpos, self._v, a)
        d.time = t
        (mujoco.mj_forward if forward else mujoco.mj_kinematics)(m, d)

    def positions(self, times: np.ndarray) -> np.ndarray:
        """(F, N, 3) vehicle body origins, world frame, m, at the given times (F,) s."""
        out = np.empty((len(times), self.n, 3))
        for f, t in enumerate(times):
            self.set_time(float(t), forward=False)
            out[f] = self.data.xpos[self.body_ids]
        return out


def _one_line(e: Exception) -> str:
    return " ".join(str(e).split())[:300] or type(e).__name__


def check_run_dir(run_dir: Path) -> None:
    """Raise UsageError (one line naming the file) unless render can read run_dir's scene.xml
    and log.npz: checked in the calling process, before any renderer or subprocess starts."""
    try:
        _Replay(run_dir)
    except RenderError as e:
        raise UsageError(str(e)) from None


def _read_meta(run_dir: Path) -> dict:
    """Scenario name and paper from scenario.toml (or metrics.json), tolerant of their absence."""
    meta = {"name": run_dir.name, "paper": "none"}
    try:
        data = tomllib.loads((run_dir / "scenario.toml").read_text())
        meta["name"] = str(data.get("name", meta["name"]))
        meta["paper"] = str(data.get("paper", "none"))
    except (OSError, tomllib.TOMLDecodeError):
        try:
            meta["name"] = str(json.loads((run_dir / "metrics.json").read_text()).get("scenario", meta["name"]))
        except (OSError, ValueError):
            pass
    return meta


# ----------------------------------------------------------------------------- camera framing


@dataclass(frozen=True, slots=True)
class CameraTrack:
    """A free-camera path: lookat (F, 3) m world, distance (F,) m, fixed azimuth/elevation (deg).

    MuJoCo convention: the camera looks along (cos el cos az, cos el sin az, sin el) from
    lookat - distance * that vector; elevation < 0 looks down.
    """

    times: np.ndarray
    lookat: np.ndarray
    distance: np.ndarray
    azimuth: float
    elevation: float

    def at(self, t: float) -> tuple[np.ndarray, float]:
        """Lookat (3,) and distance (m) at time t (s), linear between track samples."""
        look = np.array([np.interp(t, self.times, self.lookat[:, j]) for j in range(3)])
        return look, float(np.exp(np.interp(t, self.times, np.log(self.distance))))


def camera_track(times: np.ndarray, pos: np.ndarray, *, aspect: float, smooth: float, fovy: float = FOVY_TRACK,
                 margin: float = 1.2, min_distance: float = 6.0, body_radius: float = 1.0,
                 anchors: np.ndarray | None = None, in_use: np.ndarray | None = None) -> CameraTrack:
    """Frame the swarm and its anchors at every sample: times (F,) s, pos (F, N, 3) m world the
    vehicles; anchors (A, 3) m world, of which those of in_use (F, A) bool are framed at each
    sample (the anchors the swarm ranges to; none if not given).

    1. Direction, fixed for the run, from the horizontal layout about the centroid (all samples):
       azimuth perpendicular to the principal axis of largest spread, turned to look north-ish
       (east on the right); looking north when the layout is nearly isotropic. Elevation
       -(20 + 25 s_minor / s_major) deg: a line is seen from low, a 2-D layout from higher up.
    2. Lookat: the middle of the box around the framed points (the vehicles and the anchors in
       use), Gaussian-smoothed in time (sigma = `smooth` samples, zero phase).
    3. Distance: the smallest that keeps every framed point (a sphere of `body_radius` m) inside the
       picture with `margin`: in camera axes (right x, up y, forward z) an offset d from the
       lookat needs D >= margin (|x| + R) / tan(hfov / 2) - z and likewise for y with fovy;
       then the Gaussian of a running maximum (+-2 sigma) in log space, so the camera backs off
       ahead of a growing spread instead of lagging behind it; never below `min_distance` m.
    aspect: width / height of the picture; fovy: vertical field of view, deg.
    """

    F = len(times)
    sigma = max(smooth, 1e-6)
    centroid = pos.mean(axis=1)
    rel = (pos - centroid[:, None])[..., :2].reshape(-1, 2)
    ev, evec = np.linalg.eigh(rel.T @ rel / max(len(rel), 1))
    s_minor, s_major = np.sqrt(np.maximum(ev, 0.0))
    if s_major < 1e-6 or s_minor > 0.7 * s_major:
        azimuth = 90.0  # isotropic or a single vehicle: look north, east to the right
        ratio = 1.0 if s_major >= 1e-6 else 0.2
    else:
        major = evec[:, 1]
        azimuth = math.degrees(math.atan2(major[1], major[0])) + 90.0
        if math.sin(math.radians(azimuth)) < 0:  # prefer looking north-ish: east on the right
            azimuth -= 180.0
        azimuth = (azimuth + 180.0) % 360.0 - 180.0
        ratio = s_minor / s_major
    elevation = -(20.0 + 25.0 * ratio)
    points, framed = pos, np.ones(pos.shape[:2], bool)
    if anchors is not None and len(anchors):
        points = np.concatenate([pos, np.broadcast_to(anchors, (F, *np.shape(anchors)))], axis=1)
        framed = np.concatenate([framed, in_use], axis=1)
    box = np.where(framed[..., None], points, np.nan)
    middle = (np.nanmin(box, axis=1) + np.nanmax(box, axis=1)) / 2
    lookat = gaussian_filter1d(middle, sigma, axis=0, mode="nearest") if F > 1 else middle
    az, el = math.radians(azimuth), math.radians(elevation)
    fwd = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    right = np.array([math.sin(az), -math.cos(az), 0.0])
    up = np.cross(right, fwd)
    d = points - lookat[:, None]  # (F, M, 3)
    ty = math.tan(math.radians(fovy) / 2)
    tx = ty * aspect
    need_x = margin * (np.abs(d @ right) + body_radius) / tx - d @ fwd
    need_y = margin * (np.abs(d @ up) + body_radius) / ty - d @ fwd
    dist = np.maximum(min_distance, np.where(framed, np.maximum(need_x, need_y), -np.inf).max(axis=1))
    if F > 1:
        win = 2 * int(math.ceil(2 * sigma)) + 1
        dist = np.exp(gaussian_filter1d(np.log(maximum_filter1d(dist, win, mode="nearest")), sigma, mode="nearest"))
    return CameraTrack(np.asarray(times, float), lookat, dist, azimuth, elevation)


# ----------------------------------------------------------------------------------- drawing


@dataclass(frozen=True, slots=True)
class _Style:
    marker_px: float = 6.0  # on-screen marker radius, px, for vehicles smaller than that
    trail_px: float = 2.0  # trail line width, px
    labels: bool = True
    droplines: bool = True  # vertical line from each far vehicle's marker to the ground (z = 0)
    links: str = "nearest"  # UWB links drawn: "nearest" (each vehicle's `nearest` shortest), "epoch" (all), "none"
    nearest: int = 2
    error_scale: float | None = None  # the error segment and ellipse drawn this many times their size; None: auto_error_scale
    reference: bool = True  # the reference paths
    legend: bool = True  # the legend and the scale bar

    def __post_init__(self):
        if self.links not in LINKS:
            raise ValueError(f"links must be one of {', '.join(LINKS)}, got {self.links!r}")
        if self.nearest < 1:
            raise ValueError(f"nearest must be >= 1, got {self.nearest}")
        if self.error_scale is not None and not self.error_scale > 0:
            raise ValueError(f"error_scale must be positive, got {self.error_scale}")


class _Painter:
    """Two offscreen renderers (tracking view, PiP) and the drawing of one composed frame."""

    def __init__(self, replay: _Replay, width: int, height: int, *, shadow_size: int, samples: int, pip_vehicle: int | None, style: _Style):
        mujoco = _mujoco()

        for name, v in (("width", width), ("height", height)):
            if v < 16 or v % 2:
                raise ValueError(f"{name} must be an even number of pixels >= 16 (H.264 yuv420p), got {v}")
        m = replay.model
        m.vis.quality.shadowsize = max(0, int(shadow_size))
        m.vis.quality.offsamples = max(0, int(samples))
        m.vis.global_.offwidth = max(int(m.vis.global_.offwidth), width)
        m.vis.global_.offheight = max(int(m.vis.global_.offheight), height)
        self.replay, self.width, self.height, self.style = replay, width, height, style
        self.renderer = mujoco.Renderer(m, height, width)
        if shadow_size <= 0:
            self.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        self.cam = mujoco.MjvCamera()
        self.cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        self.zfar0 = float(m.vis.map.zfar)
        self.reference = replay.overlays.reference if style.reference else None  # (T, N, 3) m world at overlays.time
        self.pip = None
        if pip_vehicle:
            if not 1 <= pip_vehicle <= replay.n:
                raise ValueError(f"pip_vehicle must be in 1..{replay.n}, got {pip_vehicle}")
            self.pip_cam = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, f"uav{pip_vehicle}/cam")
            if self.pip_cam < 0:
                raise RenderError(f"scene has no camera uav{pip_vehicle}/cam for the picture-in-picture")
            cw, ch = m.cam_resolution[self.pip_cam]
            ph = 2 * round(0.32 * height / 2)
            pw = 2 * round(ph * cw / ch / 2)
            self.pip = mujoco.Renderer(m, ph, pw)
            if shadow_size <= 0:
                self.pip.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
            self.pip_label = f"uav{pip_vehicle}/cam"

    def close(self) -> None:
        self.renderer.close()
        if self.pip is not None:
            self.pip.close()

    def frame(self, t: float, look: np.ndarray, dist: float, az: float, el: float, trails: np.ndarray | None, overlay: list[str]) -> np.ndarray:
        """One composed RGB frame (H, W, 3) uint8 at time t (s) with the given free camera.

        trails: (N, P, 3) m world, each vehicle's recent positions (oldest first), or None.
        """

        rp, m = self.replay, self.replay.model
        rp.set_time(t)
        self.cam.lookat[:] = look
        self.cam.distance, self.cam.azimuth, self.cam.elevation = dist, az, el
        # Far plane (units of extent) beyond the farthest vehicle, even for km-wide scenes.
        need = 4.0 * (dist + float(np.linalg.norm(rp.data.xpos[rp.body_ids] - look, axis=1).max())) / m.stat.extent
        m.vis.map.zfar = max(self.zfar0, need)
        self.renderer.update_scene(rp.data, self.cam)
        gl = self.renderer.scene.camera[0]
        proj = _Projection(gl, self.width, self.height)
        pos = rp.data.xpos[rp.body_ids]
        px_per_m = proj.px_per_metre(pos)  # (N,) at each vehicle's depth
        small = px_per_m * 1.0 < 2.0 * self.style.marker_px  # a vehicle spans ~1 m either side
        scn = self.renderer.scene
        if trails is not None:
            for i in range(rp.n):
                P = trails[i]
                for j in range(len(P) - 1):
                    rgba = rp.colors[i].copy()
                    rgba[3] = 0.15 + 0.75 * (j + 1) / (len(P) - 1)
                    _add_line(scn, P[j], P[j + 1], self.style.trail_px, rgba)
        ov = rp.overlays
        src, dst, nlos = ov.links(t)
        ranged, ranged_nlos = len(src), int(nlos.sum())
        if self.style.links == "none":
            src, dst, nlos = src[:0], dst[:0], nlos[:0]
        elif self.style.links == "nearest":
            keep = nearest_links(rp.data.site_xpos[src], rp.data.site_xpos[dst], rp.site_vehicle[src], rp.site_vehicle[dst], self.style.nearest)
            src, dst, nlos = src[keep], dst[keep], nlos[keep]
        for a, b, bad in zip(src, dst, nlos):
            _add_line(scn, rp.data.site_xpos[a], rp.data.site_xpos[b], 1.5, NLOS_RGBA if bad else LOS_RGBA)
        for i in np.flatnonzero(small):
            _add_sphere(scn, pos[i], self.style.marker_px / px_per_m[i], rp.colors[i])
            if self.style.droplines and pos[i, 2] > 0:  # altitude cue: a thin line down to the ground
                _add_line(scn, pos[i], np.array([pos[i, 0], pos[i, 1], 0.0]), 1.0, np.array([*rp.colors[i][:3], 0.45], np.float32))
        img = np.ascontiguousarray(self.renderer.render())
        m.vis.map.zfar = self.zfar0
        lw = max(1, round(self.height / 360))
        if self.reference is not None:  # on the picture: as 3-D lines they would double a frame's cost on llvmpipe
            lo, hi = np.searchsorted(ov.time, [t - REFERENCE_SPAN[0], t + REFERENCE_SPAN[1]])
            ref = self.reference[max(0, lo - 1) : hi + 1]  # (P, N, 3): the span, and the rows either side
            uv, front = proj.pixels(ref.reshape(-1, 3))
            uv, front = uv.reshape(*ref.shape[:2], 2), front.reshape(ref.shape[:2])
            for i in range(rp.n):
                if len(ref) > 1 and front[:, i].all():
                    cv2.polylines(img, [np.round(uv[:, i]).astype(np.int32)], False, REFERENCE_RGB, 1, cv2.LINE_AA)
        fixed = ov.fixed(t)
        if self.style.legend:  # under the anchors, estimates and numbers: a legend never hides them
            _scale_bar(img, float(proj.px_per_metre(np.asarray(look, float)[None])[0]))
            _legend(img, self._legend_entries(fixed is not None, ov.uwb is not None and self.style.links != "none"))
        if rp.anchor_ids.size:  # constant-size markers: a 10 cm site is below a pixel at swarm scale
            uv, front = proj.pixels(rp.data.site_xpos[rp.anchor_ids])
            for (u, v) in uv[front].round().astype(int):
                r = int(round(0.8 * self.style.marker_px))
                cv2.fillPoly(img, [np.array([[u, v - r], [u + r, v], [u, v + r], [u - r, v]])], ANCHOR_RGB, cv2.LINE_AA)
        estimate = ov.estimate(t)
        if estimate is not None:  # the estimate: an error segment from the true vehicle, its 3-sigma ellipse
            for i in np.flatnonzero(np.isfinite(estimate[0][:, 0])):
                for line in error_drawing(pos[i], pos[i] + estimate[0][i], estimate[1][i], self.style.error_scale):
                    uv, front = proj.pixels(line)
                    if front.all():
                        cv2.polylines(img, [np.round(uv).astype(np.int32)], False, ESTIMATE_RGB, lw, cv2.LINE_AA)
        if self.style.labels:  # vehicle numbers; with GNSS, green with a fix, red without
            uv, front = proj.pixels(pos)
            for i in range(rp.n):
                if front[i] and -50 < uv[i, 0] < self.width + 50 and -50 < uv[i, 1] < self.height + 50:
                    off = max(self.style.marker_px, px_per_m[i] * 0.8) + 3
                    color = (255, 255, 255) if fixed is None else (120, 255, 120) if fixed[i] else (255, 90, 90)
                    _text(img, str(i + 1), (int(uv[i, 0] + off), int(uv[i, 1] - off)), 0.45 * self.height / 540, color)
        overlay = list(overlay)
        if fixed is not None:
            overlay.append(f"GNSS fix {int(fixed.sum())}/{rp.n}")
        if ov.uwb is not None:
            shown = {"nearest": f", {len(src)} drawn", "epoch": "", "none": ", none drawn"}[self.style.links]
            overlay.append(f"UWB {ranged} links ranged ({ranged_nlos} NLOS){shown}")
        if self.pip is not None:
            self.pip.update_scene(rp.data, self.pip_cam)
            sub = self.pip.render()
            ph, pw = sub.shape[:2]
            pad = max(8, self.height // 60)
            y0, x0 = pad, self.width - pw - pad  # top right: usually sky, away from the text
            cv2.rectangle(img, (x0 - 2, y0 - 2), (x0 + pw + 1, y0 + ph + 1), (235, 235, 235), 2)
            img[y0 : y0 + ph, x0 : x0 + pw] = sub
            _text(img, self.pip_label, (x0 + 6, y0 + ph - 8), 0.4 * self.height / 540)
        for k, line in enumerate(overlay):
            s = 0.55 * self.height / 540
            _text(img, line, (int(12 * s / 0.55), int((26 + 24 * k) * s / 0.55)), s)
        return img

    def _legend_entries(self, gnss: bool, uwb: bool) -> list[tuple[str, tuple, str]]:
        """(kind, RGB, text) of what this run's frames show: kind "line", "ring", "diamond", "dot" or "text"."""
        rp, ov = self.replay, self.replay.overlays
        out = [("dot", tuple(int(c) for c in 255 * rp.colors[0][:3]), "vehicle (true), its trail")]
        if self.reference is not None:
            out.append(("line", REFERENCE_RGB, f"reference path, {-REFERENCE_SPAN[0]:g} s to +{REFERENCE_SPAN[1]:g} s"))
        if ov.series is not None:
            scale = "" if self.style.error_scale == 1 else f" (x{self.style.error_scale:g})"
            out.append(("line", ESTIMATE_RGB, f"error of {ov.estimator}{' (flown on)' if ov.flown else ''}{scale}"))
            out.append(("ring", ESTIMATE_RGB, f"3-sigma ellipse, horizontal{scale}"))
        if uwb:
            what = f" ({self.style.nearest} shortest per vehicle)" if self.style.links == "nearest" else ""
            out.append(("line", tuple(int(c) for c in 255 * LOS_RGBA[:3]), f"UWB LOS{what}"))
            out.append(("line", tuple(int(c) for c in 255 * NLOS_RGBA[:3]), "UWB NLOS"))
        if rp.anchor_ids.size:
            out.append(("diamond", ANCHOR_RGB, "UWB anchor"))
        if gnss and self.style.labels:
            out.append(("text", (120, 255, 120), "GNSS fix; red: none"))
        return out


def nearest_links(a: np.ndarray, b: np.ndarray, va: np.ndarray, vb: np.ndarray, k: int) -> np.ndarray:
    """(L,) bool: the links each vehicle keeps when it keeps its k shortest (a union over vehicles).

    a, b: (L, 3) m world, the two ends of each link; va, vb: (L,) 0-based vehicle of each end, -1
    for an anchor.
    """
    length = np.linalg.norm(a - b, axis=1)
    keep = np.zeros(len(length), bool)
    for v in np.unique(np.concatenate([va, vb])):
        if v < 0:
            continue
        mine = np.flatnonzero((va == v) | (vb == v))
        keep[mine[np.argsort(length[mine], kind="stable")[:k]]] = True
    return keep


def error_drawing(truth: np.ndarray, estimate: np.ndarray, cov: np.ndarray, scale: float = 1.0, sigmas: float = 3.0,
                  points: int = 48) -> list[np.ndarray]:
    """The polylines (each (P, 3) m world) that show one estimate: the segment from the true
    position to the estimate, and the sigmas-sigma ellipse of the horizontal covariance
    (cov[:2, :2]) about the estimate, in the horizontal plane at its height; both `scale` times
    their size about the true position. truth, estimate: (3,) m world; cov: (3, 3) m^2 (NaN: no ellipse).
    """
    end = truth + scale * (estimate - truth)
    out = [np.stack([truth, end])]
    c = np.asarray(cov, float)[:2, :2]
    if np.isfinite(c).all():
        w, V = np.linalg.eigh((c + c.T) / 2)
        a = np.linspace(0.0, 2 * np.pi, points + 1)
        xy = (V * (scale * sigmas * np.sqrt(np.maximum(w, 0.0)))) @ np.stack([np.cos(a), np.sin(a)])
        out.append(np.column_stack([end[0] + xy[0], end[1] + xy[1], np.full(points + 1, end[2])]))
    return out


def auto_error_scale(sizes: np.ndarray, px_per_m: np.ndarray, height: int) -> float:
    """The factor an estimate's drawing is magnified by when none is given: the smallest round
    factor (1, 2 or 5 x 10^k, at least 1) at which the median drawing spans ERROR_PX x height
    pixels. sizes: (F, N) m, each vehicle's drawing size at each frame (Overlays.error_sizes, NaN
    without an estimate); px_per_m: (F,) px per m at the camera's lookat; height: px."""
    drawn = sizes * np.asarray(px_per_m, float)[:, None]
    drawn = drawn[np.isfinite(drawn) & (drawn > 0)]
    if not drawn.size:
        return 1.0
    need = ERROR_PX * height / float(np.median(drawn))
    if need <= 1.0:
        return 1.0
    e = 10.0 ** math.floor(math.log10(need))
    return next(f * e for f in (1, 2, 5, 10) if f * e >= need)


def _with_error_scale(style: _Style, replay: _Replay, track: CameraTrack, height: int) -> _Style:
    """style with its error_scale resolved (auto_error_scale when None) for the frames of track."""
    if style.error_scale is not None:
        return style
    f_px = height / 2 / math.tan(math.radians(FOVY_TRACK) / 2)
    sizes = replay.overlays.error_sizes(track.times)
    return dataclasses.replace(style, error_scale=auto_error_scale(sizes, f_px / track.distance, height))


def _scale_bar(img: np.ndarray, px_per_m: float) -> None:
    """A scale bar at the bottom left: a round length (1, 2 or 5 x 10^k m) of about a sixth of the
    width at the depth of the camera's lookat (the swarm's middle); img RGB, modified in place."""
    H, W = img.shape[:2]
    if not np.isfinite(px_per_m) or px_per_m <= 0:
        return
    target = W / 6 / px_per_m
    e = 10.0 ** math.floor(math.log10(target))
    length = max(f * e for f in (1, 2, 5) if f * e <= target)
    n = int(round(length * px_per_m))
    s = 0.45 * H / 540
    x0, y0 = int(14 * H / 540) + 4, H - int(22 * H / 540) - 4
    lw = max(2, round(H / 270))
    for c, w in (((20, 20, 20), lw + 2), ((255, 255, 255), lw)):
        cv2.line(img, (x0, y0), (x0 + n, y0), c, w)
        for x in (x0, x0 + n):
            cv2.line(img, (x, y0 - 3 * lw), (x, y0), c, w)
    _text(img, f"{length:g} m (at the swarm)", (x0, y0 - 4 * lw), s)


def _legend(img: np.ndarray, entries: list[tuple[str, tuple, str]]) -> None:
    """The legend in the bottom-right corner: a dark box with one swatch and text per entry
    (kind, RGB, text) of _Painter._legend_entries, left out of a picture too small to hold it;
    img RGB, modified in place."""
    H, W = img.shape[:2]
    s = max(0.32, 0.38 * H / 540)  # smaller text loses its spaces
    th = max(1, round(s * 2))
    row = int(50 * s) + 2
    sw = int(22 * H / 540) + 4  # swatch width
    pad = int(6 * H / 540) + 2
    tw = max(cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, s, th)[0][0] for _, _, text in entries)
    w, h = pad * 3 + sw + tw, pad * 2 + row * len(entries)
    x0, y0 = W - w - pad, H - h - pad
    if x0 < 0 or y0 < 0:  # a picture too small to hold it goes without
        return
    box = img[y0 : y0 + h, x0 : x0 + w]
    box[:] = (0.35 * box + 0.65 * 25).astype(np.uint8)  # darkened, still see-through
    lw = max(1, round(H / 360))
    for k, (kind, rgb, text) in enumerate(entries):
        cy, cx = y0 + pad + row * k + row // 2, x0 + pad + sw // 2
        if kind == "line":
            cv2.line(img, (x0 + pad, cy), (x0 + pad + sw, cy), rgb, lw + 1)
        elif kind == "ring":
            cv2.ellipse(img, (cx, cy), (sw // 2, row // 3), 0, 0, 360, rgb, lw)
        elif kind == "diamond":
            r = row // 3
            cv2.fillPoly(img, [np.array([[cx, cy - r], [cx + r, cy], [cx, cy + r], [cx - r, cy]])], rgb)
        elif kind == "dot":
            cv2.circle(img, (cx, cy), row // 3, rgb, -1)
        else:
            _text(img, "12", (x0 + pad, cy + row // 4), s, rgb)
        _text(img, text, (x0 + 2 * pad + sw, cy + row // 4), s)


class _Projection:
    """Pinhole projection of the rendered OpenGL camera (mjvGLCamera) to pixels.

    Frustum values are at the near plane: x in [center - width, center + width], y in
    [bottom, top]; pixel rows grow downwards.
    """

    def __init__(self, gl, width: int, height: int):
        self.pos = np.array(gl.pos, float)
        self.fwd = np.array(gl.forward, float)
        self.up = np.array(gl.up, float)
        self.right = np.cross(self.fwd, self.up)
        self.near, self.c, self.w = gl.frustum_near, gl.frustum_center, gl.frustum_width
        self.b, self.t = gl.frustum_bottom, gl.frustum_top
        if self.w <= 0:  # 0 means: from the viewport aspect ratio (set by mjr_render)
            self.w = (self.t - self.b) / 2 * width / height
        self.W, self.H = width, height

    def pixels(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """p (N, 3) m world -> pixel coordinates (N, 2) (u right, v down) and in-front mask (N,)."""
        d = p - self.pos
        z = d @ self.fwd
        zz = np.where(z > 1e-9, z, 1e-9)
        x, y = self.near * (d @ self.right) / zz, self.near * (d @ self.up) / zz
        u = (x - (self.c - self.w)) / (2 * self.w) * self.W
        v = (1.0 - (y - self.b) / (self.t - self.b)) * self.H
        return np.column_stack([u, v]), z > 1e-9

    def px_per_metre(self, p: np.ndarray) -> np.ndarray:
        """(N,) pixels per metre of a small object at points p (N, 3), by its depth."""
        z = np.maximum((p - self.pos) @ self.fwd, 1e-9)
        return self.near * self.H / ((self.t - self.b) * z)


def _add_sphere(scn, pos: np.ndarray, radius: float, rgba: np.ndarray) -> None:
    """Append a decorative sphere (radius m, world pos (3,) m) to an mjvScene if there is room."""
    mujoco = _mujoco()

    if scn.ngeom >= scn.maxgeom:
        return
    g = scn.geoms[scn.ngeom]
    mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_SPHERE, np.array([radius, 0, 0], float), np.asarray(pos, float), np.eye(3).ravel(), rgba)
    g.emission = 0.35
    g.category = mujoco.mjtCatBit.mjCAT_DECOR
    scn.ngeom += 1


def _add_line(scn, a: np.ndarray, b: np.ndarray, width_px: float, rgba: np.ndarray) -> None:
    """Append a line segment a -> b (3,) m world, width in pixels, to an mjvScene if there is room."""
    mujoco = _mujoco()

    if scn.ngeom >= scn.maxgeom:
        return
    g = scn.geoms[scn.ngeom]
    mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_LINE, np.zeros(3), np.zeros(3), np.eye(3).ravel(), rgba)
    mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_LINE, width_px, np.asarray(a, float), np.asarray(b, float))
    g.category = mujoco.mjtCatBit.mjCAT_DECOR
    scn.ngeom += 1


def _text(img: np.ndarray, s: str, org: tuple[int, int], scale: float, color: tuple = (255, 255, 255)) -> None:
    """Text (white unless `color`, RGB) with a dark outline, legible on sky and on grass (img RGB,
    modified in place)."""

    th = max(1, round(scale * 2))
    # The outline is the same text shifted by one pixel in eight directions: a thicker stroke
    # would not do, OpenCV's glyph advance grows with the thickness.
    x, y = org
    for dx, dy in ((-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)):
        cv2.putText(img, s, (x + dx, y + dy), cv2.FONT_HERSHEY_SIMPLEX, scale, (20, 20, 20), th, cv2.LINE_AA)
    cv2.putText(img, s, org, cv2.FONT_HERSHEY_SIMPLEX, scale, color, th, cv2.LINE_AA)


# ---------------------------------------------------------------------------------- the jobs


def _default_pip(replay: _Replay, pip_vehicle: int | None) -> int | None:
    """pip_vehicle as given (0 = none); None = vehicle 1 for seed 004 (leader camera), else none."""
    if pip_vehicle is None:
        return 1 if replay.meta["paper"] == "004" else None
    return pip_vehicle or None


def _trails(times: np.ndarray, pos: np.ndarray, f: int, n_frames: int, points: int = 16) -> np.ndarray | None:
    """(N, P, 3) positions of frames f - n_frames .. f (at most `points` of them), or None."""
    if n_frames < 1 or f == 0:
        return None
    idx = np.unique(np.linspace(max(0, f - n_frames), f, points).round().astype(int))
    return None if idx.size < 2 else np.transpose(pos[idx], (1, 0, 2))


def _track(replay: _Replay, times: np.ndarray, pos: np.ndarray, aspect: float, fps: float) -> CameraTrack:
    """The camera path of a video: the vehicles pos (F, N, 3) m world at times (F,) s, and the
    anchors the swarm ranged to at the latest UWB sample of each time (all of them without UWB)."""
    anchors = replay.data.site_xpos[replay.anchor_ids].copy()
    in_use = np.ones((len(times), len(anchors)), bool)
    if replay.overlays.uwb is not None:
        for f, t in enumerate(times):
            src, dst, _ = replay.overlays.links(float(t))
            in_use[f] = np.isin(replay.anchor_ids, np.concatenate([src, dst]))
    return camera_track(times, pos, aspect=aspect, smooth=0.75 * fps, anchors=anchors, in_use=in_use)


def render_run(run_dir: Path, out: Path | None = None, *, width: int = 960, height: int = 540, fps: int = 30, speed: float = 1.0,
               max_seconds: float | None = None, shadow_size: int = 1024, samples: int = 0, pip_vehicle: int | None = None,
               progress: bool = False, trail: float = 3.0, marker_px: float = 6.0, labels: bool = True, links: str = "nearest",
               nearest: int = 2, error_scale: float | None = None, legend: bool = True, reference: bool = True, force: bool = False) -> Path:
    """Render a run directory to an MP4; returns its path (default `run_dir/video.mp4`).

    Video time runs at `speed` x simulated time from the first logged instant; frame k shows
    simulated time t0 + k * speed / fps. Frames: round(video seconds * fps), the video lasting
    (t_end - t0) / speed s or `max_seconds` if shorter. width, height: even pixel counts.
    shadow_size: shadow map size in px (0 = shadows off); samples: multisampling (0 = off).
    pip_vehicle: 1-based vehicle whose `uav{i}/cam` is shown in the corner; None = from
    scenario.toml (vehicle 1 when paper = "004", else none); 0 = none. trail: trail length in
    video seconds (0 = none); marker_px: on-screen radius (px) of the markers of far vehicles;
    labels: write vehicle numbers. links: the UWB links drawn, "nearest" (default: of the links
    ranged at the latest sample, each vehicle's `nearest` shortest, anchors included), "epoch" (all
    of them) or "none". error_scale: the estimate's error segment and 3-sigma ellipse are drawn this
    many times their size (1: to scale; the legend says so otherwise); None: 1 unless the drawings
    would be too small to see, then a round factor for the whole video (auto_error_scale). legend: the legend and the
    scale bar; reference: the reference paths. The file is written beside `out` and renamed when
    complete; an existing `out` is refused (RunError) unless force.
    """

    run_dir = Path(run_dir)
    out = Path(out) if out is not None else run_dir / "video.mp4"
    if fps <= 0 or speed <= 0:
        raise ValueError(f"fps and speed must be positive, got fps={fps}, speed={speed}")
    if out.is_dir():  # before any work; new_file checks again, atomically
        raise RunError(f"{out}: is a directory; give a file name")
    if out.exists() and not force:
        raise RunError(f"{out}: already exists (use --force to replace it)")
    look = dict(marker_px=marker_px, labels=labels, links=links, nearest=nearest, error_scale=error_scale, legend=legend, reference=reference)
    style = _Style(**look)
    backend = choose_backend()
    if backend is not None:
        call = dict(fn="render_run", run_dir=str(run_dir), out=str(out), width=width, height=height, fps=fps, speed=speed, max_seconds=max_seconds,
                    shadow_size=shadow_size, samples=samples, pip_vehicle=pip_vehicle, progress=progress, trail=trail, force=force, **look)
        return _delegate(backend, call)
    replay = _Replay(run_dir)
    t0, t1 = float(replay.time[0]), float(replay.time[-1])
    video_s = (t1 - t0) / speed
    if max_seconds is not None:
        video_s = min(video_s, max_seconds)
    n_frames = max(1, int(round(video_s * fps)))
    times = t0 + np.arange(n_frames) * speed / fps
    pos = replay.positions(times)
    track = _track(replay, times, pos, width / height, fps)
    style = _with_error_scale(style, replay, track, height)
    painter = _Painter(replay, width, height, shadow_size=shadow_size, samples=samples, pip_vehicle=_default_pip(replay, pip_vehicle), style=style)
    trail_frames = int(round(trail * fps))
    try:
        with tempfile.TemporaryFile() as ffmpeg_log, new_file(out, force=force, suffix=".mp4") as partial:
            writer = imageio.get_writer(partial, fps=fps, codec="libx264", pixelformat="yuv420p", macro_block_size=2, quality=None,
                                        output_params=["-crf", "20", "-preset", "veryfast"], ffmpeg_log_level="error")
            failed = ""
            try:
                for f in tqdm(range(n_frames), desc=f"render {replay.meta['name']}", unit="frame", disable=not progress, leave=False):
                    overlay = [replay.meta["name"], f"t = {times[f]:7.2f} s" + (f"   x{speed:g}" if speed != 1 else "")]
                    img = painter.frame(float(times[f]), track.lookat[f], float(track.distance[f]), track.azimuth, track.elevation,
                                        _trails(times, pos, f, trail_frames), overlay)
                    with stderr_to(ffmpeg_log) if f == 0 else contextlib.nullcontext():  # the first frame starts ffmpeg
                        writer.append_data(img)
                writer.close()
            except OSError as e:  # ffmpeg stopped (its stderr is in ffmpeg_log, not on the terminal)
                with contextlib.suppress(Exception):
                    writer.close()
                failed = _one_line(e)
            except BaseException:
                # interrupted or failed: the partial file is discarded, so a writer that cannot close
                # cleanly (ffmpeg stopped mid-frame) must not replace the reason we are unwinding
                with contextlib.suppress(Exception):
                    writer.close()
                raise
            reason = last_line(written(ffmpeg_log)) or failed  # ffmpeg runs with -v error: a line it wrote is an error
            if reason:  # the partial file is discarded
                raise RunError(f"{out}: ffmpeg could not write the video: {reason}")
    finally:
        painter.close()
    return out


def save_frame(run_dir: Path, t: float, path: Path, *, width: int = 960, height: int = 540, shadow_size: int = 1024, samples: int = 0,
               pip_vehicle: int | None = None, trail: float = 3.0, marker_px: float = 6.0, labels: bool = True, links: str = "nearest",
               nearest: int = 2, error_scale: float | None = None, legend: bool = True, reference: bool = True) -> Path:
    """Write one PNG of the tracking view at simulated time t (s), as the video (30 fps, 1x) shows it.

    Options as for `render_run`. Returns the path.
    """

    path = Path(path)
    look = dict(marker_px=marker_px, labels=labels, links=links, nearest=nearest, error_scale=error_scale, legend=legend, reference=reference)
    style = _Style(**look)
    backend = choose_backend()
    if backend is not None:
        call = dict(fn="save_frame", run_dir=str(run_dir), t=t, path=str(path), width=width, height=height, shadow_size=shadow_size,
                    samples=samples, pip_vehicle=pip_vehicle, trail=trail, **look)
        return _delegate(backend, call)
    replay = _Replay(Path(run_dir))
    fps = 30
    t0, t1 = float(replay.time[0]), float(replay.time[-1])
    times = t0 + np.arange(int(math.floor((t1 - t0) * fps)) + 1) / fps
    pos = replay.positions(times)
    track = _track(replay, times, pos, width / height, fps)
    style = _with_error_scale(style, replay, track, height)
    painter = _Painter(replay, width, height, shadow_size=shadow_size, samples=samples, pip_vehicle=_default_pip(replay, pip_vehicle), style=style)
    try:
        f = int(np.clip(round((t - t0) * fps), 0, len(times) - 1))
        look, dist = track.at(t)
        img = painter.frame(float(t), look, dist, track.azimuth, track.elevation, _trails(times, pos, f, int(round(trail * fps))),
                            [replay.meta["name"], f"t = {t:7.2f} s"])
    finally:
        painter.close()
    path.parent.mkdir(parents=True, exist_ok=True)
    imageio.imwrite(path, img)
    return path


def main(argv: list[str] | None = None) -> int:
    """`python -m testbed.outputs.render RUN_DIR [--out FILE] [...]`; also the subprocess entry (--call JSON)."""
    ap = argparse.ArgumentParser(prog="python -m testbed.outputs.render", description="Render a run directory to MP4 (or one PNG with --frame T).")
    ap.add_argument("run_dir", nargs="?", type=Path)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--frame", type=float, metavar="T", help="write one PNG at simulated time T (s) instead of a video")
    ap.add_argument("--width", type=int, default=960)
    ap.add_argument("--height", type=int, default=540)
    ap.add_argument("--fps", type=int, default=30)
    ap.add_argument("--speed", type=float, default=1.0)
    ap.add_argument("--max-seconds", type=float)
    ap.add_argument("--shadow-size", type=int, default=1024)
    ap.add_argument("--samples", type=int, default=0)
    ap.add_argument("--pip", type=int, dest="pip_vehicle")
    ap.add_argument("--call", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    try:
        if a.call:
            worker_init(os.getppid())  # SIGTERM cleans up; dies with the parent that delegated
            kw = json.loads(a.call)
            fn = {"render_run": render_run, "save_frame": save_frame}[kw.pop("fn")]
            print(fn(**kw))
            return 0
        if a.run_dir is None:
            ap.error("RUN_DIR is required")
        common = dict(width=a.width, height=a.height, shadow_size=a.shadow_size, samples=a.samples, pip_vehicle=a.pip_vehicle)
        if a.frame is not None:
            print(save_frame(a.run_dir, a.frame, a.out or a.run_dir / f"frame_{a.frame:g}.png", **common))
        else:
            print(render_run(a.run_dir, a.out, fps=a.fps, speed=a.speed, max_seconds=a.max_seconds, progress=True, **common))
    except (RenderError, ValueError, RunError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
