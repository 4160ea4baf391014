"""The headless renderer: a short video of a tiny run directory decodes, is not blank, moves.

Software OpenGL (EGL/llvmpipe) at 160 x 96 pixels keeps this to a few seconds.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from testbed import scenario as scenario_mod

LEADER_FOLLOWER = """
name = "render-test"
description = "two vehicles 20 m apart, leader camera in the corner"
paper = "004"
duration = 2.0
[trajectory]
kind = "leader-follower"
"""


def _write_run(scenario, out: Path) -> Path:
    """A run directory: through testbed.runner when it is there, else by hand (same contract)."""
    try:
        from testbed.runner import run
    except ImportError:
        run = None
    if run is not None:
        run(scenario, out, plots=False)
        return out
    from testbed.log import save_npz
    from testbed.simulate import simulate

    log, physics = simulate(scenario)
    out.mkdir(parents=True)
    (out / "scene.xml").write_text(physics.to_xml())
    (out / "scenario.toml").write_text(scenario_mod.dumps(scenario))
    save_npz(out / "log.npz", log)
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    from testbed.render import RenderError, choose_backend

    try:
        choose_backend()
    except RenderError as e:
        pytest.skip(str(e))
    base = tmp_path_factory.mktemp("render")
    toml = base / "lf.toml"
    toml.write_text(LEADER_FOLLOWER)
    return {
        "cross": _write_run(scenario_mod.load("phase-cross-h000", duration=3.0), base / "cross"),
        "lf": _write_run(scenario_mod.load(str(toml)), base / "lf"),
    }


def _decode(path: Path) -> np.ndarray:
    import imageio.v3 as iio

    return np.stack(list(iio.imiter(path)))


def test_video_decodes_with_expected_frames_and_is_not_blank(runs):
    from testbed.render import render_run

    # 3 s logged at 2x would last 1.5 s; max_seconds cuts it to 1 s = 10 frames at 10 fps.
    out = render_run(runs["cross"], width=160, height=96, fps=10, speed=2.0, max_seconds=1.0)
    assert out == runs["cross"] / "video.mp4" and out.stat().st_size > 0
    frames = _decode(out)
    assert frames.shape == (10, 96, 160, 3)
    assert all(f.std() > 5.0 for f in frames), "a frame is blank"
    # below the text overlay (time stamp), the picture changes: the follower and its trail move
    scene = frames[:, 24:].astype(int)
    assert np.abs(scene[-1] - scene[0]).max() > 60 and (np.abs(scene[-1] - scene[0]).sum(axis=-1) > 30).sum() >= 4
    assert not any(p.name.endswith(".partial.mp4") for p in runs["cross"].iterdir())


def test_leader_camera_picture_in_picture_and_save_frame(runs, tmp_path):
    import imageio.v3 as iio

    from testbed.render import render_run, save_frame

    a = iio.imread(save_frame(runs["lf"], 1.0, tmp_path / "pip.png", width=320, height=180))
    b = iio.imread(save_frame(runs["lf"], 1.0, tmp_path / "nopip.png", width=320, height=180, pip_vehicle=0))
    assert a.shape == (180, 320, 3) and a.std() > 5.0
    # paper = "004" puts uav1/cam in the top-right corner: that corner changes, the rest of the
    # picture does not. Two renders of the same instant can differ in a few pixels of a thin line
    # (llvmpipe, measured: 2 pixels of a 1.5-px UWB link in 1 of 15 runs of this pair after another
    # video in the same process, none in 16 renders alone): at most 0.1 % of the rest may differ.
    diff = np.abs(a.astype(int) - b.astype(int)).sum(axis=2) > 0
    corner = np.zeros_like(diff)
    corner[: 180 // 2, 320 // 2 :] = True
    assert diff[corner].sum() > 0.1 * corner.sum()  # the inset, 58 px tall (measured: 3458 of 14400 px change)
    assert diff[~corner].sum() <= 0.001 * (~corner).sum()
    out = render_run(runs["lf"], tmp_path / "lf.mp4", width=320, height=180, fps=5, max_seconds=1.0)
    assert _decode(out).shape == (5, 180, 320, 3)


def test_odd_size_is_refused(runs):
    from testbed.render import render_run

    with pytest.raises(ValueError, match="even"):
        render_run(runs["lf"], runs["lf"] / "odd.mp4", width=161, height=96, max_seconds=0.2)


def test_no_backend_names_the_libraries(monkeypatch):
    import testbed.render as render

    monkeypatch.setattr(render, "_probe_in_process", lambda: (False, "ImportError: no libEGL"))
    monkeypatch.setattr(render, "_probe_subprocess", lambda backend: (False, f"{backend} missing"))
    with pytest.raises(render.RenderError, match="libegl1 libopengl0 libgl1-mesa-dri.*libosmesa6"):
        render.choose_backend()


def test_camera_track_keeps_everyone_in_view():
    from testbed.render import camera_track

    # two vehicles drifting apart along x (a pair seen from the side), 20 -> 220 m
    t = np.linspace(0.0, 10.0, 101)
    pos = np.zeros((101, 2, 3))
    pos[:, 0, 0] = 10.0 + 10.0 * t
    pos[:, 1, 0] = -10.0 - 10.0 * t
    pos[..., 2] = 30.0
    track = camera_track(t, pos, aspect=16 / 9, smooth=7.5)
    assert abs(track.azimuth - 90.0) < 1e-6  # looking north: the pair side by side
    assert np.allclose(track.lookat, [0.0, 0.0, 30.0])
    # every vehicle projects inside the picture at every sample
    half_w = np.tan(np.radians(45.0) / 2) * 16 / 9
    assert np.all(np.abs(pos[:, :, 0]) / track.distance[:, None] < half_w)
    assert np.all(np.diff(track.distance) > 0)  # smooth: backs off monotonically


def test_fallback_renders_in_a_subprocess(runs, tmp_path, monkeypatch):
    """When this process cannot render, another backend that works renders in a subprocess."""
    import imageio.v3 as iio

    import testbed.render as render

    monkeypatch.setattr(render, "_probe_in_process", lambda: (False, "pretend this backend failed"))
    monkeypatch.setenv("MUJOCO_GL", "osmesa")  # so the probe tries egl, which works on this machine
    if not render._probe_subprocess("egl")[0]:
        pytest.skip("egl does not work in a subprocess here")
    out = render.save_frame(runs["lf"], 0.5, tmp_path / "sub.png", width=160, height=96)
    assert out == tmp_path / "sub.png" and iio.imread(out).shape == (96, 160, 3)
