"""testbed view: the Rerun recording of a run or a replay, read back with Rerun's own reader
(rerun.chunk.RrdReader): entity paths, row counts per timeline, and the values against the run's
files (poses, links, ellipsoids, NEES); the missing extra, the command's line and its refusals."""
from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

import testbed
from testbed.cli import main
from testbed.plugins.collect import read_tracks
from testbed.viewer import SIGMAS, ellipsoids

rerun_chunk = pytest.importorskip("rerun.chunk", reason="the viz extra (rerun-sdk)")
ROOT = Path(__file__).resolve().parent.parent


def _read(path: Path) -> tuple[dict[str, int], dict[str, dict[str, list]], set[str]]:
    """(temporal rows per entity, {entity: {column: values of every temporal row}}, static entities)."""
    rows: dict[str, int] = defaultdict(int)
    cols: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    static: set[str] = set()
    for chunk in rerun_chunk.RrdReader(path).stream():
        if chunk.is_static:
            static.add(chunk.entity_path)
            continue
        rows[chunk.entity_path] += chunk.num_rows
        batch = chunk.to_record_batch()
        for name in (n for n in batch.schema.names if ":" in n):  # components (not the timeline, row ids)
            cols[chunk.entity_path][name] += batch.column(name).to_pylist()
    return dict(rows), cols, static


@pytest.fixture(scope="module")
def denied(tmp_path_factory):
    """2 s of coop-denied (anchors, GNSS sky, network) with coop.ins scored offline; its buildings
    replaced by a wall between two columns of the swarm, so that UWB links are NLOS from the start."""
    out = tmp_path_factory.mktemp("view") / "denied"
    wall = 'world.obstacles=[{type="box", pos=[-25.0, -3.5, 10.0], size=[25.0, 0.2, 10.0]}]'
    assert main(["run", "coop-denied", "--duration", "2", "--estimator", "coop.ins", "--set", wall, "--out", str(out),
                 "--no-plots"]) == 0
    return out


def test_a_run_reads_back_with_every_entity_and_its_rows(denied, tmp_path):
    rrd = testbed.view(denied, tmp_path / "d.rrd")
    rows, cols, static = _read(rrd)
    r = testbed.load_run(denied)
    K, N = r.log["truth/pos"].shape[:2]
    # poses: one row per log instant per vehicle, at the truth's positions (float32 in Rerun)
    for i in range(1, N + 1):
        assert rows[f"/world/vehicles/uav{i}"] == K
        assert f"/world/vehicles/uav{i}/airframe/boxes" in static
    tr = np.array(cols["/world/vehicles/uav5"]["Transform3D:translation"]).reshape(K, 3)
    assert np.allclose(tr, r.log["truth/pos"][:, 4], atol=1e-4)
    assert {"/world/scene/planes", "/world/scene/boxes", "/world/anchors", "/world/paths/truth", "/world/paths/reference"} <= static
    # UWB links: one row per epoch on both entities, every logged link exactly once, by LOS/NLOS
    uwb = r.stream("uwb")
    epochs = np.unique(uwb.time).size
    assert uwb.nlos.any() and not uwb.nlos.all()
    for path, want in (("/world/uwb/los", int((~uwb.nlos).sum())), ("/world/uwb/nlos", int(uwb.nlos.sum()))):
        assert rows[path] == epochs
        assert sum(len(s or []) for s in cols[path]["LineStrips3D:strips"]) == want
    # GNSS: fixes per epoch, the fix state of every vehicle at every log instant
    gnss = r.stream("gnss")
    assert rows["/world/gnss/fixes"] == np.unique(gnss.time).size
    assert rows["/world/gnss/state"] == K and rows["/plots/gnss/vehicles_with_fix"] == K
    assert np.array_equal(np.ravel(cols["/plots/gnss/vehicles_with_fix"]["Scalars:scalars"]), r.log["gnss/fix"].sum(axis=1))
    # estimates: a point per estimate, an ellipsoid per estimate with a covariance, error and NEES series
    with np.load(denied / "estimates.npz") as z:
        track = read_tracks({k: z[k] for k in z.files})["coop.ins"]
    every_nees = []
    for (target, q), s in track.items():
        if q != "position":  # velocity and attitude are scored, not drawn
            continue
        n_cov = int(s.has_cov.sum())
        assert rows[f"/world/estimates/coop.ins/{target}"] == s.time.size
        assert rows[f"/world/estimates/coop.ins/{target}/sigma3"] == n_cov
        assert rows[f"/plots/error/coop.ins/{target}"] == s.time.size
        assert rows[f"/plots/error/coop.ins/{target}/sigma3"] == rows[f"/plots/nees/coop.ins/{target}"] == n_cov
        every_nees += [x for row in cols[f"/plots/nees/coop.ins/{target}"]["Scalars:scalars"] for x in row]
    assert len(track) > 0 and rows["/plots/nees/coop.ins/interval_95"] == 2
    # the NEES series are the scoring's: their mean is metrics.json's ANEES (float64 both)
    assert np.mean(every_nees) == pytest.approx(r.metrics["estimators"]["coop.ins"]["anees_position"], rel=1e-9)


def test_the_ellipsoid_is_the_3_sigma_surface_of_the_covariance(denied, tmp_path):
    rrd = testbed.view(denied, tmp_path / "d.rrd")
    _, cols, _ = _read(rrd)
    with np.load(denied / "estimates.npz") as z:
        s = read_tracks({k: z[k] for k in z.files})["coop.ins"][("uav3", "position")]
    C = s.cov[s.has_cov]
    e = cols["/world/estimates/coop.ins/uav3/sigma3"]
    half = np.array([row[0] for row in e["Ellipsoids3D:half_sizes"]])
    quat = np.array([row[0] for row in e["Ellipsoids3D:quaternions"]])
    from scipy.spatial.transform import Rotation

    R = Rotation.from_quat(quat).as_matrix()
    back = R @ (((half / SIGMAS) ** 2)[:, :, None] * np.swapaxes(R, 1, 2))
    assert np.allclose(back, C, rtol=1e-4, atol=1e-7 * np.abs(C).max())  # float32 in the file
    h, q = ellipsoids(C)  # and the function itself, in float64, to round-off
    R64 = Rotation.from_quat(q).as_matrix()
    assert np.allclose(R64 @ (((h / SIGMAS) ** 2)[:, :, None] * np.swapaxes(R64, 1, 2)), C, rtol=1e-9, atol=1e-15)


def test_camera_detections_and_an_estimate_relative_to_the_leader(tmp_path):
    out = tmp_path / "vis"
    assert main(["run", "visnav", "--duration", "2", "--estimator", "visnav.ekf", "--out", str(out), "--no-plots"]) == 0
    rows, cols, _ = _read(testbed.view(out))
    assert (out / "recording.rrd").is_file()
    r = testbed.load_run(out)
    cam = r.stream("camera")
    assert rows["/camera/pixels"] == rows["/world/camera/detections"] == np.unique(cam.time).size
    assert sum(len(s) for s in cols["/world/camera/detections"]["LineStrips3D:strips"]) == len(cam)
    # visnav.ekf estimates relative to the leader: placed in the world with its true pose, the
    # distance to the truth is the norm of the (leader-frame) error
    p = np.array([row[0] for row in cols["/world/estimates/visnav.ekf/uav2"]["Points3D:positions"]])
    err = np.array(cols["/plots/error/visnav.ekf/uav2"]["Scalars:scalars"])
    with np.load(out / "estimates.npz") as z:
        s = read_tracks({k: z[k] for k in z.files})["visnav.ekf"][("uav2", "position")]
    assert s.frame == "uav1" and p.shape == (s.time.size, 3)
    true = np.column_stack([np.interp(s.time, r.time, r.log["truth/pos"][:, 1, a]) for a in range(3)])
    assert np.allclose(np.linalg.norm(p - true, axis=1), np.linalg.norm(err, axis=1), atol=1e-4)


def test_a_replay_directory_is_viewed_with_its_dataset_truth(tmp_path, capsys):
    rep = tmp_path / "rep"
    assert main(["replay", str(ROOT / "examples/replay/spec.toml"), "--out", str(rep), "--no-plots"]) == 0  # coop.centralized
    assert capsys.readouterr().out.splitlines()[-1] == f"replay directory -> {rep}"  # the command's last line
    rows, cols, static = _read(testbed.view(rep))
    assert rows["/world/estimates/coop.centralized/uav1/uwb"] == 5 and rows["/plots/nees/coop.centralized/uav1/uwb"] == 5
    assert len([p for p in static if p.startswith("/world/paths/truth/")]) == 18  # the dataset's bodies
    m = json.loads((rep / "metrics.json").read_text())["estimators"]["coop.centralized"]
    every = [x for p, c in cols.items() if p.startswith("/plots/nees/coop.centralized/uav") for row in c["Scalars:scalars"] for x in row]
    assert m["unscored_estimates"] == {} and np.mean(every) == pytest.approx(m["anees_position"], rel=1e-9)


def test_the_command_line_its_line_and_its_refusals(denied, tmp_path, capsys):
    out = tmp_path / "v.rrd"
    assert main(["view", str(denied), "--out", str(out)]) == 0
    assert capsys.readouterr().out.splitlines()[-1].startswith(f"Rerun recording of {denied} -> {out}")
    assert main(["view", str(denied), "--out", str(out)]) == 2  # exists: --force to replace it
    assert "already exists" in capsys.readouterr().err
    assert main(["view", str(denied), "--out", str(out), "--force"]) == 0
    mine = tmp_path / "notes.rrd"
    mine.write_text("my notes")
    assert main(["view", str(denied), "--out", str(mine), "--force"]) == 2  # not a recording: never replaced
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a Rerun recording" in err and mine.read_text() == "my notes"
    assert main(["view", str(tmp_path), "--out", str(tmp_path / "x.rrd")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a run directory" in err and not (tmp_path / "x.rrd").exists()
    assert not [p.name for p in tmp_path.iterdir() if ".testbed-" in p.name]  # no temporary file left


def test_without_the_viz_extra_one_line_exit_2(denied, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)  # `import rerun` raises ImportError
    assert main(["view", str(denied), "--out", str(tmp_path / "v.rrd")]) == 2
    err = capsys.readouterr().err
    assert err == "testbed: error: testbed view needs rerun-sdk: install the viz extra: pip install '.[viz]'\n"
    assert not (tmp_path / "v.rrd").exists()


def test_spawn_opens_the_written_file_in_the_viewer(denied, tmp_path, monkeypatch):
    import testbed.viewer as viewer

    started = []
    monkeypatch.setattr(viewer.subprocess, "Popen", lambda cmd, **kw: started.append(cmd))
    out = testbed.view(denied, tmp_path / "s.rrd", spawn=True)
    assert started == [[sys.executable, "-m", "rerun", str(out)]] and out.is_file()
