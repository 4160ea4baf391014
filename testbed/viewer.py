"""`testbed view RUN`: an interactive 3-D recording of a run or a replay (Rerun, `.rrd`); the
Python API calls it as `testbed.view` (this module is not named `view`: it would hide that function).

The recording is read from the directory alone (a run's log.npz, scene.xml, scenario.toml and
estimates.npz; a replay's estimates.npz and, when its dataset is still where it was replayed
from, the dataset's truth). Everything is on one timeline, `time` (s of simulated time; a
replay's window clock). Entity paths (N vehicles `uavI`, estimators by their key EST, TARGET a
vehicle or a site such as `uav3/uwb`):

  world/scene/{planes,boxes,cylinders,spheres,capsules}  static geometry (welded to the world)
  world/anchors                      static points, the UWB anchors (labels `anchorK`)
  world/vehicles/uavI                Transform3D per log instant: true pose, world ENU
  world/vehicles/uavI/airframe/...   static, the airframe's visual geoms in the body frame
  world/paths/truth, world/paths/reference   static line strips, one per vehicle
  world/estimates/EST/TARGET         Points3D per estimate: the estimated position (world)
  world/estimates/EST/TARGET/sigma3  Ellipsoids3D per estimate with a covariance: 3-sigma
  world/uwb/los, world/uwb/nlos      LineStrips3D per UWB epoch: the links ranged, by LOS/NLOS
  world/gnss/fixes                   Points3D per GNSS epoch: the fixes (antenna positions measured)
  world/gnss/state                   Points3D per log instant: 1 m above each vehicle, green with a GNSS
                                     fix, red without (runs that log `gnss/fix`: [sensors.gnss.sky])
  world/camera/detections            LineStrips3D per camera epoch: camera site to each LED seen
  camera/pixels                      Points2D per camera epoch: the detections on the image (px)
  plots/error/EST/TARGET             Scalars: position error (estimate - truth, the estimate's frame) x, y, z m
  plots/error/EST/TARGET/sigma3      Scalars: +3 sigma x, y, z and -3 sigma x, y, z (m) of the estimate
  plots/nees/EST/TARGET              Scalars: position NEES of each estimate with a covariance
  plots/nees/EST/interval_95         Scalars: the interval a consistent estimator's NEES of one
                                     sample falls in with 95 % (testbed.scoring.metrics.anees_interval)
  plots/gnss/vehicles_with_fix       Scalars: how many vehicles have a GNSS fix

An estimate relative to a vehicle (visnav) is placed in the world with that vehicle's true pose,
for the picture only (a replay without truth draws it as it is); truth is used nowhere else but for the errors and NEES (scoring). Links and
detections are drawn between the sites' true positions at the instant they were measured.
Only the plugin estimators are recorded (a run's estimates.npz); a scenario pipeline's built-in
estimators keep only their scores. Every array goes to Rerun as columns (rerun.send_columns):
one call per entity, no loop over samples.
"""
from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from estimators.core import nees
from testbed.config import scenario as scenario_mod
from testbed.errors import RunError, UsageError
from testbed.log import NpzLog
from testbed.scoring.metrics import anees_interval
from testbed.outdir import check_new_file, new_file
from testbed.plugins.collect import ESTIMATES_FILE, Series, Track, load_tracks, natural
from testbed.plugins.context import make_context
from testbed.plugins.truth import Truth, errors
from testbed.outputs.render_overlay import LOS_RGBA, NLOS_RGBA
from testbed.sim.world import build, lever_arms

APP = "testbed"
TIMELINE = "time"
INSTALL = "testbed view needs rerun-sdk: install the viz extra: pip install '.[viz]'"
SIGMAS = 3.0  # the ellipsoids' and error bounds' width, in standard deviations
PALETTE = np.array([[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
                    [140, 86, 75], [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207]], np.uint8)
FIX_RGB, NO_FIX_RGB = np.array([40, 200, 60], np.uint8), np.array([230, 40, 40], np.uint8)


def _rerun():
    """The rerun module; UsageError naming the extra to install when it is missing."""
    try:
        return importlib.import_module("rerun")  # lazy: an optional extra, loaded only by `view`
    except ImportError:
        raise UsageError(INSTALL) from None


def kind_of(path: Path) -> str:
    """"run" or "replay" for a directory the testbed wrote, else RunError naming what is missing."""
    path = Path(path)
    if all((path / f).is_file() for f in ("log.npz", "scene.xml", "scenario.toml")):
        return "run"
    if all((path / f).is_file() for f in ("spec.toml", ESTIMATES_FILE, "metrics.json")):
        return "replay"
    raise RunError(f"{path}: not a run directory (log.npz, scene.xml, scenario.toml) "
                   f"nor a replay directory (spec.toml, {ESTIMATES_FILE}, metrics.json)")


def view(run_dir: str | Path, out: str | Path | None = None, *, force: bool = False, spawn: bool = False) -> Path:
    """Write the Rerun recording of a run or replay directory (module docstring); returns its path.

    out: the .rrd file (default RUN_DIR/recording.rrd), written whole into a temporary sibling and
    renamed on success; an existing file is replaced only with force, and only if it is a Rerun
    recording (anything else is refused, force or not). spawn: then open it in the Rerun viewer
    (a separate process). RunError for a directory that is neither a run nor a replay;
    UsageError when rerun-sdk (the `viz` extra) is not installed.
    """
    run_dir = Path(run_dir)
    kind = kind_of(run_dir)
    rr = _rerun()
    out = Path(out) if out is not None else run_dir / "recording.rrd"
    check_new_file(out, force=force)
    if out.exists() and not _is_recording(out):
        raise RunError(f"{out}: exists and is not a Rerun recording; refusing to replace it, --force or not")
    with new_file(out, force=force, suffix=".rrd") as tmp:
        rec = rr.RecordingStream(APP)
        rec.save(tmp)
        try:
            (_log_run if kind == "run" else _log_replay)(rr, rec, run_dir)
        finally:  # the file complete (or, on an error, closed before new_file removes it)
            rec.flush()
            rec.disconnect()
    if spawn:
        subprocess.Popen(spawn_command(out), start_new_session=True)
    return out


def _is_recording(path: Path) -> bool:
    """Does the file start with Rerun's .rrd magic bytes (b"RRF2")?"""
    try:
        with open(path, "rb") as f:
            return f.read(4) == b"RRF2"
    except OSError:
        return False


def spawn_command(path: Path) -> list[str]:
    """The command that opens a recording in the Rerun viewer."""
    return [sys.executable, "-m", "rerun", os.fspath(path)]


# ------------------------------------------------------------------------------------------ run


def _log_run(rr, rec, run_dir: Path) -> None:
    """Everything of the module docstring that a run directory holds."""
    scenario = scenario_mod.load(str(run_dir / "scenario.toml"))
    physics = build(scenario)
    context = make_context(scenario, lever_arms(physics), "view", {})
    model = mujoco.MjModel.from_xml_path(str(run_dir / "scene.xml"))
    with NpzLog(run_dir / "log.npz") as npz:
        keys = set(npz)
        log = {k: npz[k] for k in keys if not k.startswith(("imu/", "qvel", "ctrl")) and k != "qpos"}
    time = log["time"]
    truth = Truth(log, context)
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    _log_scene(rr, rec, model)
    anchors = context.anchors
    if anchors:
        rec.log("world/anchors", rr.Points3D(np.array(list(anchors.values())), labels=list(anchors), radii=0.3,
                                             colors=[[240, 190, 25]]), static=True)
    _log_vehicles(rr, rec, model, context.vehicles, time, log["truth/pos"], log["truth/quat"])
    strips = lambda a: [a[:, i] for i in range(a.shape[1])]  # noqa: E731 (K, N, 3) -> N strips
    rec.log("world/paths/truth", rr.LineStrips3D(strips(log["truth/pos"]), labels=list(context.vehicles),
                                                 colors=[[200, 200, 200]], radii=0.03), static=True)
    if "reference/pos" in log:
        rec.log("world/paths/reference", rr.LineStrips3D(strips(log["reference/pos"]), colors=[[120, 160, 255]],
                                                         radii=0.02), static=True)

    def site_pos(names: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """(M, 3) m world: true position of site names[m] at log instant rows[m] (anchors fixed)."""
        out = np.empty((len(names), 3))
        for name in np.unique(names).tolist():
            m = names == name
            out[m] = anchors[name] if name in anchors else truth.at(name, "position", time[rows[m]])
        return out

    if "uwb/time" in log and log["uwb/time"].size:
        _log_links(rr, rec, log, site_pos)
    if "gnss/time" in log and log["gnss/time"].size:
        _log_epochs(rr, rec, "world/gnss/fixes", log["gnss/time"], rr.Points3D, positions=log["gnss/value"],
                    radii=np.full(len(log["gnss/time"]), 0.15))
    if "gnss/fix" in log:
        fix = log["gnss/fix"].astype(bool)
        K, N = fix.shape
        rec.send_columns("world/gnss/state", indexes=[rr.TimeColumn(TIMELINE, duration=time)],
                         columns=rr.Points3D.columns(positions=log["truth/pos"].reshape(-1, 3) + [0.0, 0.0, 1.0],
                                                     colors=np.where(fix.reshape(-1, 1), FIX_RGB, NO_FIX_RGB),
                                                     radii=np.full(K * N, 0.6)).partition(np.full(K, N)))
        rec.send_columns("plots/gnss/vehicles_with_fix", indexes=[rr.TimeColumn(TIMELINE, duration=time)],
                         columns=rr.Scalars.columns(scalars=fix.sum(axis=1).astype(float)))
    if "camera/time" in log and log["camera/time"].size:
        ends = np.stack([site_pos(log["camera/src"], log["camera/state_index"]),
                         site_pos(log["camera/dst"], log["camera/state_index"])], axis=1)
        _log_epochs(rr, rec, "world/camera/detections", log["camera/time"], rr.LineStrips3D, strips=ends)
        if "camera/pixel" in log:
            _log_epochs(rr, rec, "camera/pixels", log["camera/time"], rr.Points2D, positions=log["camera/pixel"])
    tracks = load_tracks(run_dir / ESTIMATES_FILE)
    if tracks:
        _log_estimates(rr, rec, tracks, truth)


def _log_scene(rr, rec, model: mujoco.MjModel) -> None:
    """The geoms welded to the world (floor, buildings, obstacles), static, world frame."""
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    ids = np.flatnonzero(model.body_weldid[model.geom_bodyid] == 0)
    _log_geoms(rr, rec, "world/scene", model, ids, data.geom_xpos[ids], data.geom_xmat[ids].reshape(-1, 3, 3))


def _log_vehicles(rr, rec, model: mujoco.MjModel, vehicles: tuple[str, ...], time: np.ndarray, pos: np.ndarray,
                  quat: np.ndarray) -> None:
    """Each vehicle's true pose (pos (K, N, 3) m, quat (K, N, 4) wxyz) as a Transform3D per log
    instant, and its airframe (the visual geoms, group 2, of the first vehicle's body tree in the
    base body's frame) as static children."""
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    base = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"{vehicles[0]}/base") if vehicles else -1
    shapes = None
    if base >= 0:
        ids = np.flatnonzero((model.body_rootid[model.geom_bodyid] == model.body_rootid[base]) & (model.geom_group == 2))
        R = data.xmat[base].reshape(3, 3)
        shapes = (ids, (data.geom_xpos[ids] - data.xpos[base]) @ R, R.T @ data.geom_xmat[ids].reshape(-1, 3, 3))
    index = [rr.TimeColumn(TIMELINE, duration=time)]
    xyzw = quat[..., [1, 2, 3, 0]]
    for i, name in enumerate(vehicles):
        rec.send_columns(f"world/vehicles/{name}", indexes=index,
                         columns=rr.Transform3D.columns(translation=pos[:, i], quaternion=xyzw[:, i]))
        if shapes is not None:
            _log_geoms(rr, rec, f"world/vehicles/{name}/airframe", model, *shapes)


def _log_geoms(rr, rec, path: str, model: mujoco.MjModel, ids: np.ndarray, pos: np.ndarray, R: np.ndarray) -> None:
    """Geoms ids (G,) at positions pos (G, 3) m and orientations R (G, 3, 3) of the parent frame,
    static, one entity per kind under `path`. Colours: the material's, else the geom's."""
    if not ids.size:
        return
    q = Rotation.from_matrix(R).as_quat()  # xyzw, as Rerun takes them
    size = model.geom_size[ids]
    mat = model.geom_matid[ids]
    rgba = np.where((mat >= 0)[:, None], model.mat_rgba[np.maximum(mat, 0)], model.geom_rgba[ids])
    color = (np.clip(rgba, 0, 1) * 255).astype(np.uint8)
    kind = model.geom_type[ids]
    extent = 2.0 * float(np.abs(pos).max(initial=100.0))  # an infinite plane, drawn this wide (m)
    G = mujoco.mjtGeom
    for name, k, make in (
        ("planes", G.mjGEOM_PLANE, lambda m: rr.Boxes3D(
            half_sizes=np.column_stack([np.where(size[m, 0] > 0, size[m, 0], extent), np.where(size[m, 1] > 0, size[m, 1], extent),
                                        np.full(m.sum(), 0.01)]), centers=pos[m], quaternions=q[m], colors=color[m], fill_mode="solid")),
        ("boxes", G.mjGEOM_BOX, lambda m: rr.Boxes3D(half_sizes=size[m], centers=pos[m], quaternions=q[m], colors=color[m],
                                                     fill_mode="solid")),
        ("cylinders", G.mjGEOM_CYLINDER, lambda m: rr.Cylinders3D(lengths=2 * size[m, 1], radii=size[m, 0], centers=pos[m],
                                                                  quaternions=q[m], colors=color[m], fill_mode="solid")),
        ("capsules", G.mjGEOM_CAPSULE, lambda m: rr.Capsules3D(lengths=2 * size[m, 1], radii=size[m, 0],
                                                               translations=pos[m] - R[m][:, :, 2] * size[m, 1:2],
                                                               quaternions=q[m], colors=color[m])),
        ("spheres", G.mjGEOM_SPHERE, lambda m: rr.Points3D(pos[m], radii=size[m, 0], colors=color[m])),
    ):
        m = kind == k
        if m.any():
            rec.log(f"{path}/{name}", make(m), static=True)


def _log_epochs(rr, rec, path: str, t: np.ndarray, archetype, **fields: np.ndarray) -> None:
    """Rows (M,) at times t (M,) s, grouped by time into one entry per epoch: archetype.columns of
    fields (each (M, ...)), partitioned by epoch, sent in one call."""
    order = np.argsort(t, kind="stable")
    times, counts = np.unique(t[order], return_counts=True)
    rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=times)],
                     columns=archetype.columns(**{k: v[order] for k, v in fields.items()}).partition(counts))


def _log_links(rr, rec, log: dict, site_pos) -> None:
    """The UWB links of each epoch between the two sites' true positions, LOS and NLOS apart
    (an epoch with none of one kind logs an empty set, so the last epoch's links do not linger)."""
    t, rows = log["uwb/time"], log["uwb/state_index"]
    nlos = log["uwb/nlos"].astype(bool) if "uwb/nlos" in log else np.zeros(t.size, bool)
    ends = np.stack([site_pos(log["uwb/src"], rows), site_pos(log["uwb/dst"], rows)], axis=1)
    epochs = np.unique(t)
    epoch = np.searchsorted(epochs, t)
    for path, m, rgba in (("world/uwb/los", ~nlos, LOS_RGBA), ("world/uwb/nlos", nlos, NLOS_RGBA)):
        order = np.argsort(epoch[m], kind="stable")
        counts = np.bincount(epoch[m], minlength=epochs.size)
        rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=epochs)],
                         columns=rr.LineStrips3D.columns(strips=ends[m][order]).partition(counts))
        rec.log(path, rr.LineStrips3D.from_fields(colors=[(rgba * 255).astype(np.uint8)], radii=[0.04]), static=True)


# ------------------------------------------------------------------------------------ estimates


def _log_estimates(rr, rec, tracks: dict[str, Track], truth) -> None:
    """Per estimator and position series: the estimate in the world and its 3-sigma ellipsoid;
    with truth (an object with .at(target, quantity, t, frame), e.g. testbed.plugins.truth.Truth),
    the error and NEES time series with their bounds."""
    lo, hi = anees_interval(3, 1, 0.95)
    for e, (key, track) in enumerate(tracks.items()):
        rgb = PALETTE[e % len(PALETTE)]
        span = []
        for (target, q), s in sorted(track.items(), key=lambda kv: natural(kv[0][0])):
            if q != "position" or not s.time.size:
                continue
            span += [s.time[0], s.time[-1]]
            index = [rr.TimeColumn(TIMELINE, duration=s.time)]
            p, C = _in_world(s, truth)
            rec.send_columns(f"world/estimates/{key}/{target}", indexes=index,
                             columns=rr.Points3D.columns(positions=p, colors=np.tile(rgb, (len(p), 1)),
                                                         radii=np.full(len(p), 0.12)))
            if s.has_cov.any():
                half, quat = ellipsoids(C[s.has_cov])
                rec.send_columns(f"world/estimates/{key}/{target}/sigma3",
                                 indexes=[rr.TimeColumn(TIMELINE, duration=s.time[s.has_cov])],
                                 columns=rr.Ellipsoids3D.columns(centers=p[s.has_cov], half_sizes=half, quaternions=quat,
                                                                 colors=np.tile(rgb, (len(half), 1))))
            if truth is None:
                continue
            err = errors(truth, target, q, s.time, s.value, s.frame)
            rec.send_columns(f"plots/error/{key}/{target}", indexes=index, columns=rr.Scalars.columns(scalars=err))
            if s.has_cov.any():
                cov = s.cov[s.has_cov]
                bound = SIGMAS * np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
                cov_index = [rr.TimeColumn(TIMELINE, duration=s.time[s.has_cov])]
                rec.send_columns(f"plots/error/{key}/{target}/sigma3", indexes=cov_index,
                                 columns=rr.Scalars.columns(scalars=np.hstack([bound, -bound])))
                rec.send_columns(f"plots/nees/{key}/{target}", indexes=cov_index,
                                 columns=rr.Scalars.columns(scalars=nees(err[s.has_cov], cov)))
        if span and truth is not None:
            rec.send_columns(f"plots/nees/{key}/interval_95", indexes=[rr.TimeColumn(TIMELINE, duration=[min(span), max(span)])],
                             columns=rr.Scalars.columns(scalars=np.array([[lo, hi], [lo, hi]])))


def _in_world(s: Series, truth) -> tuple[np.ndarray, np.ndarray]:
    """(K, 3) m positions and (K, 3, 3) m^2 covariances of a position series in the world frame;
    a series relative to a vehicle is placed with that vehicle's true pose (for the picture)."""
    if s.frame == "world" or truth is None:
        return s.value, s.cov
    R = Rotation.from_quat(truth.at(s.frame, "attitude", s.time), scalar_first=True).as_matrix()
    return truth.at(s.frame, "position", s.time) + np.einsum("kij,kj->ki", R, s.value), R @ s.cov @ np.swapaxes(R, 1, 2)


def ellipsoids(cov: np.ndarray, sigmas: float = SIGMAS) -> tuple[np.ndarray, np.ndarray]:
    """Half axes (K, 3) m and orientations (K, 4) xyzw of the sigmas-sigma ellipsoids of
    covariances cov (K, 3, 3) m^2: the eigenvectors as the axes, sigmas sqrt(eigenvalues) long."""
    w, V = np.linalg.eigh(cov)
    V[:, :, 2] *= np.sign(np.linalg.det(V))[:, None]  # a proper rotation
    return sigmas * np.sqrt(np.maximum(w, 0.0)), Rotation.from_matrix(V).as_quat()


# --------------------------------------------------------------------------------------- replay


def _log_replay(rr, rec, replay_dir: Path) -> None:
    """A replay directory: its estimates; with the dataset's truth (the spec it was replayed from,
    as metrics.json names it, still in place) the bodies' true paths, the anchors, the errors and NEES."""
    from testbed.replay.recording import RecordedTruth, load_recording  # lazy: only for a replay

    tracks = load_tracks(replay_dir / ESTIMATES_FILE)
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    truth = None
    metrics = json.loads((replay_dir / "metrics.json").read_text())
    spec = metrics.get("spec")
    if metrics.get("truth") and isinstance(spec, str) and Path(spec).is_file():
        truth = RecordedTruth(load_recording(Path(spec)))
        for body, t in truth.by_body.items():
            rec.log(f"world/paths/truth/{body}", rr.LineStrips3D([t.pos[:, 0]], colors=[[200, 200, 200]]), static=True)
        if truth.anchors:
            rec.log("world/anchors", rr.Points3D(np.array(list(truth.anchors.values())), labels=list(truth.anchors),
                                                 colors=[[240, 190, 25]]), static=True)
    _log_estimates(rr, rec, tracks, truth)
