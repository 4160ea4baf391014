"""The headless renderer: a short video of a tiny run directory decodes, is not blank, moves.

Software OpenGL (EGL/llvmpipe) at 160 x 96 pixels keeps this to a few seconds.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from testbed.config import scenario as scenario_mod

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
    from testbed.sim.simulate import simulate

    log, physics = simulate(scenario)
    out.mkdir(parents=True)
    (out / "scene.xml").write_text(physics.to_xml())
    (out / "scenario.toml").write_text(scenario_mod.dumps(scenario))
    save_npz(out / "log.npz", log)
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    from testbed.outputs.render import RenderError, choose_backend

    try:
        choose_backend()
    except RenderError as e:
        pytest.skip(str(e))
    base = tmp_path_factory.mktemp("render")
    toml = base / "lf.toml"
    toml.write_text(LEADER_FOLLOWER)
    from testbed.reproduce.denied import variant

    return {
        "cross": _write_run(scenario_mod.load("phase-cross-h000", duration=3.0), base / "cross"),
        "lf": _write_run(scenario_mod.load(str(toml)), base / "lf"),
        # the closed loop: 18 vehicles flown on the distributed cooperative estimate, anchors, GNSS
        "denied": _write_run(variant(scenario_mod.load("coop-denied", duration=1.5), "coop_distributed"), base / "denied"),
    }


def _decode(path: Path) -> np.ndarray:
    import imageio.v3 as iio

    return np.stack(list(iio.imiter(path)))


def test_video_decodes_with_expected_frames_and_is_not_blank(runs):
    from testbed.outputs.render import render_run

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

    from testbed.outputs.render import render_run, save_frame

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
    from testbed.outputs.render import render_run

    with pytest.raises(ValueError, match="even"):
        render_run(runs["lf"], runs["lf"] / "odd.mp4", width=161, height=96, max_seconds=0.2)


def test_no_backend_names_the_libraries(monkeypatch):
    import testbed.outputs.render as render

    monkeypatch.setattr(render, "_probe_in_process", lambda: (False, "ImportError: no libEGL"))
    monkeypatch.setattr(render, "_probe_subprocess", lambda backend: (False, f"{backend} missing"))
    with pytest.raises(render.RenderError, match="libegl1 libopengl0 libgl1-mesa-dri.*libosmesa6"):
        render.choose_backend()


def test_camera_track_keeps_everyone_in_view():
    from testbed.outputs.render import camera_track

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

    import testbed.outputs.render as render

    monkeypatch.setattr(render, "_probe_in_process", lambda: (False, "pretend this backend failed"))
    monkeypatch.setenv("MUJOCO_GL", "osmesa")  # so the probe tries egl, which works on this machine
    if not render._probe_subprocess("egl")[0]:
        pytest.skip("egl does not work in a subprocess here")
    out = render.save_frame(runs["lf"], 0.5, tmp_path / "sub.png", width=160, height=96)
    assert out == tmp_path / "sub.png" and iio.imread(out).shape == (96, 160, 3)


# ------------------------------------------------------------------- what the frames explain


def _camera(run: Path, t: float, width: int, height: int):
    """The tracking camera of `save_frame(run, t)` as a pinhole (MuJoCo's free camera: it looks
    along (cos el cos az, cos el sin az, sin el) from lookat - distance * that, fovy 45 deg):
    returns project(p (M, 3) m world) -> (M, 2) pixels (u right, v down), and the depth (M,) m."""
    import math

    from testbed.outputs import render

    replay = render._Replay(run)
    t0, t1 = float(replay.time[0]), float(replay.time[-1])
    times = t0 + np.arange(int(math.floor((t1 - t0) * 30)) + 1) / 30
    track = render._track(replay, times, replay.positions(times), width / height, 30)
    look, dist = track.at(t)
    az, el = math.radians(track.azimuth), math.radians(track.elevation)
    fwd = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    right = np.array([math.sin(az), -math.cos(az), 0.0])
    up = np.cross(right, fwd)
    f = height / 2 / math.tan(math.radians(45.0) / 2)
    cam = look - dist * fwd

    def project(p):
        d = np.atleast_2d(p) - cam
        z = d @ fwd
        return np.column_stack([width / 2 + f * (d @ right) / z, height / 2 - f * (d @ up) / z]), z

    return project, f, right, np.array([math.cos(az), math.sin(az), 0.0]), el


def _copy_run(run: Path, dest: Path) -> Path:
    import shutil

    return Path(shutil.copytree(run, dest, ignore=shutil.ignore_patterns("plots", "*.mp4", "*.png")))


# a frame with nothing but the scene and the part under test
BARE = dict(labels=False, links="none", legend=False, reference=False, trail=0.0)


def test_estimate_ellipse_matches_the_covariance(runs, tmp_path):
    """An estimate 30 m east of vehicle 2 with a known horizontal covariance: the magenta drawing
    (segment and 3-sigma ellipse) spans, in the picture, what the 3-sigma ellipse of the covariance
    spans when projected through the tracking camera."""
    import imageio.v3 as iio

    from testbed.plugins.collect import ESTIMATES_FILE, Series, track_arrays
    from testbed.outputs.render import ESTIMATE_RGB, save_frame

    run = _copy_run(runs["cross"], tmp_path / "run")
    with np.load(run / "log.npz") as z:
        time, truth = z["time"], z["truth/pos"][:, 1]
    C = np.array([[1600.0, 600.0, 0.0], [600.0, 900.0, 0.0], [0.0, 0.0, 9.0]])  # m^2: sigma 40 m east, 30 m north
    offset = np.array([30.0, 0.0, 0.0])
    track = {("uav2", "position"): Series(time, truth + offset, np.tile(C, (len(time), 1, 1)), np.ones(len(time), bool))}
    np.savez(run / ESTIMATES_FILE, **track_arrays("est", track))
    W, H, t = 320, 180, 1.5
    with_est = iio.imread(save_frame(run, t, tmp_path / "with.png", width=W, height=H, **BARE)).astype(int)
    without = iio.imread(save_frame(runs["cross"], t, tmp_path / "without.png", width=W, height=H, **BARE)).astype(int)
    drawn = (np.abs(with_est - without).sum(axis=2) > 40) & (np.abs(with_est - ESTIMATE_RGB).sum(axis=2) < 200)
    vs, us = np.nonzero(drawn)
    assert vs.size > 50
    project, *_ = _camera(run, t, W, H)
    k = int(np.searchsorted(time, t + 1e-9)) - 1
    centre = truth[k] + offset
    # the 3-sigma ellipse of the horizontal covariance: centre + 3 L (cos a, sin a), L L' = C_xy,
    # in the horizontal plane at the estimate's height, projected through the pinhole
    a = np.linspace(0.0, 2 * np.pi, 2000)
    xy = 3 * np.linalg.cholesky(C[:2, :2]) @ np.stack([np.cos(a), np.sin(a)])
    uv, _ = project(np.column_stack([centre[0] + xy[0], centre[1] + xy[1], np.full(a.size, centre[2])]))
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    assert (hi - lo).min() > 25  # big enough for a 2-px tolerance to mean something
    assert np.abs([us.min() - lo[0], us.max() - hi[0], vs.min() - lo[1], vs.max() - hi[1]]).max() <= 2, (us.min(), us.max(), vs.min(), vs.max(), lo, hi)


def test_reference_path_is_drawn_where_it_projects(runs, tmp_path):
    """The leader and the follower fly 10 m in 2 s: the pixels the reference option changes lie on
    the projected reference paths, and cover their length."""
    import imageio.v3 as iio

    from testbed.outputs.render import save_frame

    W, H, t = 320, 180, 1.9
    bare = {**BARE, "pip_vehicle": 0}
    on = iio.imread(save_frame(runs["lf"], t, tmp_path / "on.png", width=W, height=H, **{**bare, "reference": True})).astype(int)
    off = iio.imread(save_frame(runs["lf"], t, tmp_path / "off.png", width=W, height=H, **bare)).astype(int)
    vs, us = np.nonzero(np.abs(on - off).sum(axis=2) > 30)
    project, *_ = _camera(runs["lf"], t, W, H)
    with np.load(runs["lf"] / "log.npz") as z:
        ref = z["reference/pos"]
    dense = np.concatenate([np.linspace(a, b, 20) for i in range(ref.shape[1]) for a, b in zip(ref[:-1, i], ref[1:, i])])
    uv, _ = project(dense)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
    assert vs.size >= 0.5 * np.ptp(uv[inside, 0])  # a line, at least half a pixel per pixel of its length
    near = np.hypot(us[:, None] - uv[None, :, 0], vs[:, None] - uv[None, :, 1]).min(axis=1) <= 3
    assert near.mean() > 0.95, near.mean()
    assert np.ptp(us) >= 0.8 * np.ptp(uv[inside, 0]), (np.ptp(us), np.ptp(uv[inside, 0]))  # the whole path, not a dot


def test_legend_and_scale_bar_are_in_the_corners(runs, tmp_path):
    """The closed loop (coop-denied on the distributed estimate): the legend's swatches in the bottom
    right (estimate, UWB LOS, anchor), the scale bar in the bottom left, nothing else changes."""
    import imageio.v3 as iio

    from testbed.outputs.render import ANCHOR_RGB, ESTIMATE_RGB, LOS_RGBA, save_frame

    W, H, t = 640, 360, 1.4
    on = iio.imread(save_frame(runs["denied"], t, tmp_path / "on.png", width=W, height=H)).astype(int)
    off = iio.imread(save_frame(runs["denied"], t, tmp_path / "off.png", width=W, height=H, legend=False)).astype(int)
    changed = np.abs(on - off).sum(axis=2) > 0
    corner = np.zeros_like(changed)
    corner[H // 3 :, W // 2 :] = True  # the legend
    bar = np.zeros_like(changed)
    bar[H - H // 5 :, : W // 3] = True  # the scale bar
    assert changed[corner].mean() > 0.2 and changed[bar].sum() > 100
    assert changed[~(corner | bar)].sum() <= 0.001 * (~(corner | bar)).sum()
    legend = on[H // 3 :, W // 2 :]
    for rgb in (ESTIMATE_RGB, tuple(int(c) for c in 255 * LOS_RGBA[:3]), ANCHOR_RGB):
        assert (np.abs(legend - rgb).sum(axis=2) == 0).sum() >= 15, rgb
    assert (on[bar] == 255).all(axis=-1).sum() >= 60  # the white bar


def test_phase_estimate_is_magnified_to_a_round_factor_and_drawn_to_it(runs, tmp_path):
    """The phase scenario's own estimate (phase.ekf on vehicle 6, centimetres seen from hundreds of
    metres): to scale it is below a few pixels, so the default drawing is magnified by a round
    factor (1, 2 or 5 x 10^k) and spans, in the picture, what the 3-sigma ellipse about the
    estimate's error, both magnified by that factor, span when projected through the camera."""
    import imageio.v3 as iio

    from testbed.outputs.render import ESTIMATE_RGB, save_frame
    from testbed.plugins.collect import ESTIMATES_FILE, load_tracks

    run = runs["cross"]
    bare = _copy_run(run, tmp_path / "bare")
    (bare / ESTIMATES_FILE).unlink()
    W, H, t = 320, 180, 1.5
    without = iio.imread(save_frame(bare, t, tmp_path / "without.png", width=W, height=H, **BARE)).astype(int)

    def drawn(**options):
        img = iio.imread(save_frame(run, t, tmp_path / "with.png", width=W, height=H, **BARE, **options)).astype(int)
        return np.nonzero((np.abs(img - without).sum(axis=2) > 40) & (np.abs(img - ESTIMATE_RGB).sum(axis=2) < 200))

    assert drawn(error_scale=1.0)[0].size <= 12  # to scale: a few pixels at most
    vs, us = drawn()
    assert vs.size > 40
    s = load_tracks(run / ESTIMATES_FILE)["ekf"][("uav6", "position")]
    with np.load(run / "log.npz") as z:
        time, truth = z["time"], z["truth/pos"][:, 5]
    k = int(np.searchsorted(s.time, t + 1e-9)) - 1
    error = s.value[k] - np.array([np.interp(s.time[k], time, truth[:, j]) for j in range(3)])
    here = truth[int(np.searchsorted(time, t + 1e-9)) - 1]
    project, *_ = _camera(run, t, W, H)
    a = np.linspace(0.0, 2 * np.pi, 2000)
    L = np.linalg.cholesky(s.cov[k][:2, :2])

    def miss(factor):  # px: how far the drawing's box is from the projected one at this factor
        centre = here + factor * error
        xy = factor * 3 * L @ np.stack([np.cos(a), np.sin(a)])
        uv, _ = project(np.vstack([here, np.column_stack([centre[0] + xy[0], centre[1] + xy[1], np.full(a.size, centre[2])])]))
        lo, hi = uv.min(axis=0), uv.max(axis=0)
        return np.abs([us.min() - lo[0], us.max() - hi[0], vs.min() - lo[1], vs.max() - hi[1]]).max()

    factors = [f * 10.0**e for e in range(0, 6) for f in (1, 2, 5)]
    fits = [f for f in factors if miss(f) <= 2]
    assert len(fits) == 1 and fits[0] > 1, [(f, miss(f)) for f in factors]


def test_auto_error_scale_is_the_smallest_round_factor_that_shows_the_typical_error():
    from testbed.outputs.render import ERROR_PX, auto_error_scale

    px_per_m = np.full(4, 2.0)
    # median drawing 0.04 m x 2 px/m = 0.08 px; 3 % of 540 px = 16.2 px: x202.5 needed -> 500
    sizes = np.array([[0.04, np.nan], [0.03, np.nan], [0.05, np.nan], [0.04, np.nan]])
    assert ERROR_PX == 0.03 and auto_error_scale(sizes, px_per_m, 540) == 500.0
    assert auto_error_scale(sizes * 1e3, px_per_m, 540) == 1.0  # 40 m: to scale
    assert auto_error_scale(np.full((4, 2), np.nan), px_per_m, 540) == 1.0  # no estimate


def test_vehicles_and_anchors_in_use_stay_in_the_frame(runs):
    """Every vehicle of the closed loop and every anchor it ranges to projects inside the picture
    at every frame time of the video (the camera of save_frame and render_run)."""
    from testbed.outputs import render

    W, H = 320, 180
    replay = render._Replay(runs["denied"])
    times = np.arange(0.0, 1.5, 0.1)
    pos = replay.positions(times)
    anchors = replay.data.site_xpos[replay.anchor_ids]
    assert len(anchors) == 6
    for t in times:
        project, *_ = _camera(runs["denied"], float(t), W, H)
        src, dst, _ = replay.overlays.links(float(t))
        used = anchors[np.isin(replay.anchor_ids, np.concatenate([src, dst]))]
        assert len(used) >= 1
        uv, z = project(np.vstack([replay.positions(np.array([t]))[0], used]))
        assert (z > 0).all() and (uv >= 0).all() and (uv[:, 0] <= W).all() and (uv[:, 1] <= H).all(), t


def test_nearest_links_keeps_each_vehicles_k_shortest():
    from testbed.outputs.render import nearest_links

    # vehicles 0, 1, 2 at x = 0, 1, 3 and an anchor (-1) at x = 10; links: 0-1, 1-2, 0-2, 2-anchor, 0-anchor
    x = {0: 0.0, 1: 1.0, 2: 3.0, -1: 10.0}
    ends = [(0, 1), (1, 2), (0, 2), (2, -1), (0, -1)]
    a = np.array([[x[i], 0, 0] for i, _ in ends], float)
    b = np.array([[x[j], 0, 0] for _, j in ends], float)
    va, vb = np.array([i for i, _ in ends]), np.array([j for _, j in ends])
    assert nearest_links(a, b, va, vb, 1).tolist() == [True, True, False, False, False]  # 0: 0-1, 1: 0-1, 2: 1-2
    assert nearest_links(a, b, va, vb, 2).tolist() == [True, True, True, False, False]  # 0: 0-1, 0-2; 1: both; 2: 1-2, 0-2
    assert nearest_links(a, b, va, vb, 3).all()


def test_bad_link_option_is_refused(runs):
    from testbed.outputs.render import render_run

    with pytest.raises(ValueError, match="links must be one of nearest, epoch, none"):
        render_run(runs["lf"], runs["lf"] / "x.mp4", links="all")


def test_demo_flies_and_renders_the_closed_loop_beside_the_phase_scenario(tmp_path, monkeypatch):
    """make demo: coop-denied flown on its distributed cooperative estimate, and a video of it
    beside the carrier-phase formation's (the runs and renders replaced by recorders)."""
    import testbed.demo as demo

    flown, rendered = {}, []

    def fly(sc, out, progress):
        flown[out.name] = sc
        return {"tracking_rmse_m": [0.0], "estimators": {}}

    def render(run_dir, **options):
        rendered.append(run_dir.name)
        return run_dir / "video.mp4"

    monkeypatch.setattr(demo, "run", fly)
    monkeypatch.setattr(demo, "reproduce", lambda *a, **k: None)
    monkeypatch.setattr(demo, "render_run", render)
    demo._demo(tmp_path)
    loop = flown["coop-denied-distributed"]
    assert loop.name == "coop-denied" and loop.control.feedback == "estimate:coop" and loop.duration <= 10.0
    assert [e.entry for e in loop.estimators] == ["coop.ins_distributed"]
    assert rendered == ["phase-cross-h000", "coop-denied-distributed"]
    summary = (tmp_path / "summary.md").read_text()
    assert "`coop-denied-distributed` (flown on its coop_distributed estimate, 10 s" in summary
    assert "video: `coop-denied-distributed/video.mp4`" in summary
