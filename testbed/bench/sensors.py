"""`testbed bench sensors`: cost of the sensor suite (not a test).

(a) real-time factor of a flown swarm (18 vehicles by default, `--vehicles N`; seed 001's
200 x 200 x 100 m box with 4 anchors and 3 obstacles, bases on a cubic grid 60 m / 50 m apart)
with IMU 200 Hz, GNSS 5 Hz and range-gated UWB (tag pairs within 100 m by k-d tree, and
anchors) at 10 Hz with NLOS ray casting, next to the same run without sensors
(`bare`) and plain mj_step on the same model (`mj_step`); scene compilation is timed apart;
(b) frames per second of the camera pixel path at 640 x 480 (render + code-colour detection)
next to bare mujoco.Renderer on the same scene and camera.
"""
from __future__ import annotations

import time

import mujoco
import numpy as np
import scipy.signal  # noqa: F401  imported lazily by the IMU noise model: loaded here so its import is not timed

from testbed.bench.physics import bare_times, duration_for
from testbed.bench.swarm import swarm_scenario
from testbed.config import from_dict
from testbed.config.scenario import Scenario
from testbed.sensors.camera import Camera
from testbed.sim.simulate import simulate
from testbed.sim.world import build


# seed 001's 200 x 200 x 100 m box: four anchors at the corners, two pillars and a wall
ARENA_WORLD = {
    "anchors": [[0.0, 0.0, 2.0], [200.0, 0.0, 2.0], [0.0, 200.0, 2.0], [200.0, 200.0, 2.0]],
    "obstacles": [{"type": "cylinder", "pos": [70.0, 70.0, 50.0], "size": [4.0, 50.0, 0.0]},
                  {"type": "cylinder", "pos": [130.0, 130.0, 50.0], "size": [4.0, 50.0, 0.0]},
                  {"type": "box", "pos": [100.0, 70.0, 30.0], "size": [10.0, 1.0, 30.0]}],
}


def arena_swarm(duration: float, sensors: dict, vehicles: int = 18) -> Scenario:
    """The swarm of the sensor benchmark (module docstring) with the given [sensors]."""
    return swarm_scenario(vehicles, duration, spacing=(60.0, 60.0, 50.0), origin=(40.0, 40.0, 25.0), sensors=sensors,
                          world=ARENA_WORLD, rtk=(1, 7, 12) if vehicles >= 12 else ())


def _timed(fn, repeat: int = 1) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def bench_sensors(vehicles: int = 18, duration: float | None = None, frames: int = 30, repeat: int = 1) -> dict:
    """Measure the sensor suite; returns a dict of timings (s), real-time factors and fps.

    vehicles: swarm size; duration: simulated seconds of the swarm runs (None: 20 s for 18
    vehicles, shorter for more, as bench physics); frames: rendered frames per camera timing;
    repeat: best of this many runs (the machine may be shared). CPU-time real-time factors
    (time.process_time) are given beside the wall-clock ones.
    """
    duration = duration or duration_for(vehicles)
    sensors = {"imu": {"preset": "bmi088"}, "gnss": {}, "uwb": {"preset": "dw1000", "max_range": 100.0, "link_search": "in-range"}}
    bare = arena_swarm(duration, {}, vehicles)
    full = arena_swarm(duration, sensors, vehicles)
    out: dict = {"duration_s": duration, "vehicles": bare.vehicles}
    # interleaved runs (same load), the scene compiled before each (untimed, as in bench physics);
    # rtf_mj_step: plain mj_step on the same model, for scale
    walls: dict[str, list[float]] = {"bare": [], "sensors": []}
    cpus: dict[str, list[float]] = {"bare": [], "sensors": []}
    mj_step = []
    logs = {}
    for _ in range(repeat):
        for key, sc in (("bare", bare), ("sensors", full)):
            physics = build(sc)
            t0, c0 = time.perf_counter(), time.process_time()
            logs[key] = simulate(sc, physics)[0]
            walls[key].append(time.perf_counter() - t0)
            cpus[key].append(time.process_time() - c0)
        mj_step.append(bare_times(bare))
    for key in walls:
        out[f"wall_{key}_s"] = min(walls[key])
        out[f"rtf_{key}"] = duration / out[f"wall_{key}_s"]
        out[f"cpu_rtf_{key}"] = duration / min(cpus[key])
    out["rtf_mj_step"] = duration / min(w for w, _ in mj_step)
    out["cpu_rtf_mj_step"] = duration / min(c for _, c in mj_step)
    out["build_s"] = _timed(lambda: build(full), repeat)
    log = logs["sensors"]
    out["uwb_measurements"] = int(len(log["uwb/value"]))
    out["uwb_nlos_fraction"] = float(log["uwb/nlos"].mean()) if len(log["uwb/nlos"]) else 0.0
    out["imu_samples"] = int(len(log["imu/value"]))

    # (b) camera pixel path vs bare renderer, leader-follower scene
    cam_sc = from_dict(Scenario, {"name": "bench-cam", "description": "", "duration": 1.0,
                                  "trajectory": {"kind": "leader-follower", "follower_offset": [-8.0, 0.0, 0.0]},
                                  "sensors": {"camera": {"mode": "pixels", "preset": "ideal"}}}, "bench")
    physics = build(cam_sc)
    cam = Camera(cam_sc.sensors.camera, physics, np.random.default_rng(0), 20)
    cam.sample(physics, 0.0, 0)  # warm-up: creates the renderer

    def pixel_path():
        for _ in range(frames):
            cam.sample(physics, 0.0, 0)

    renderer = mujoco.Renderer(physics.model, 480, 640)

    def bare_render():
        for _ in range(frames):
            renderer.update_scene(physics.data, camera="uav1/cam")
            renderer.render()

    bare_render()
    out["fps_renderer_bare"] = frames / _timed(bare_render, repeat)
    out["fps_camera_pixels"] = frames / _timed(pixel_path, repeat)
    renderer.close()
    cam.arrays()
    return out

