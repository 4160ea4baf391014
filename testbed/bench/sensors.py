"""`testbed bench sensors`: cost of the sensor suite (not a test).

(a) real-time factor of an 18-vehicle flown swarm (seed 001's 200 x 200 x 100 m box, bases on a
3 x 3 x 2 grid 60 m / 50 m apart, 4 anchors, 3 pillars) with IMU 200 Hz, GNSS 5 Hz and UWB on all
tag pairs and anchors at 10 Hz with NLOS ray casting, next to the same run without sensors
(`bare`) and plain mj_step on the same model (`mj_step`); scene compilation is timed apart;
(b) frames per second of the camera pixel path at 640 x 480 (render + code-colour detection)
next to bare mujoco.Renderer on the same scene and camera.
"""
from __future__ import annotations

import time

import mujoco
import numpy as np

from testbed.bench.physics import bare_rtf
from testbed.bench.swarm import swarm_scenario
from testbed.config import from_dict
from testbed.scenario import Scenario
from testbed.sensors.camera import Camera
from testbed.simulate import simulate
from testbed.world import build


# seed 001's 200 x 200 x 100 m box: four anchors at the corners, two pillars and a wall
ARENA_WORLD = {
    "anchors": [[0.0, 0.0, 2.0], [200.0, 0.0, 2.0], [0.0, 200.0, 2.0], [200.0, 200.0, 2.0]],
    "obstacles": [{"type": "cylinder", "pos": [70.0, 70.0, 50.0], "size": [4.0, 50.0, 0.0]},
                  {"type": "cylinder", "pos": [130.0, 130.0, 50.0], "size": [4.0, 50.0, 0.0]},
                  {"type": "box", "pos": [100.0, 70.0, 30.0], "size": [10.0, 1.0, 30.0]}],
}


def arena_swarm(duration: float, sensors: dict) -> Scenario:
    """The 18-vehicle swarm of the sensor benchmark (module docstring) with the given [sensors]."""
    return swarm_scenario(18, duration, spacing=(60.0, 60.0, 50.0), origin=(40.0, 40.0, 25.0), sensors=sensors,
                          world=ARENA_WORLD, rtk=(1, 7, 12))


def _timed(fn, repeat: int = 1) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def bench_sensors(duration: float = 20.0, frames: int = 30, repeat: int = 1) -> dict:
    """Measure the sensor suite; returns a dict of timings (s), real-time factors and fps.

    duration: simulated seconds of the swarm runs; frames: rendered frames per camera timing;
    repeat: best of this many runs (the machine may be shared).
    """
    sensors = {"imu": {"preset": "bmi088"}, "gnss": {}, "uwb": {"preset": "dw1000", "max_range": 100.0}}
    bare = arena_swarm(duration, {})
    full = arena_swarm(duration, sensors)
    out: dict = {"duration_s": duration, "vehicles": bare.vehicles}
    # interleaved runs (same load), the scene compiled before each (untimed, as in bench physics);
    # rtf_mj_step: plain mj_step on the same model, for scale
    walls: dict[str, list[float]] = {"bare": [], "sensors": []}
    mj_step = []
    logs = {}
    for _ in range(repeat):
        for key, sc in (("bare", bare), ("sensors", full)):
            physics = build(sc)
            t0 = time.perf_counter()
            logs[key] = simulate(sc, physics)[0]
            walls[key].append(time.perf_counter() - t0)
        mj_step.append(bare_rtf(bare))
    for key in walls:
        out[f"wall_{key}_s"] = min(walls[key])
        out[f"rtf_{key}"] = duration / out[f"wall_{key}_s"]
    out["rtf_mj_step"] = max(mj_step)
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

