"""`testbed export RUN` then `testbed replay EXPORT/spec.toml` with no options: every estimator the
export lists gives back the estimates it gave inside the simulation, to 1e-9 m (see
docs/replay.md), on coop-fg, bandwidth, a phase scenario, visnav and coop-denied (flown, its
estimator online in the loop, replayed offline); the built-ins the format cannot drive are named.

The estimators run in the simulation as [[estimators]], so their estimates are in the run's
estimates.npz: the comparison is of estimates, not of metrics."""
import contextlib
import dataclasses
import io
import json
import re
from pathlib import Path

import numpy as np
import pytest

from testbed.config import scenario
from testbed.sim import world
from testbed.api import load_run
from testbed.cli import main
from testbed.config import to_dict
from testbed.config.network import NetworkConfig
from testbed.plugins import EstimatorSpec
from testbed.plugins.collect import ESTIMATES_FILE, load_tracks
from testbed.plugins.context import make_context
from testbed.plugins.priors import priors
from testbed.sim.world import lever_arms
from testbed.plugins.defaults import default_specs, estimator_specs
from testbed.replay.export import exported_estimators
from testbed.replay.recording import load_recording
from testbed.replay.spec import load_spec
from testbed.runner import run

ROOT = Path(__file__).resolve().parents[1]
UWB_EKF = f"{ROOT / 'examples/uwb_ekf.py'}:UwbEkf"
ECHO = f"{ROOT / 'tests/export_plugins.py'}:Echo"  # folds its Context and its whole feed into its estimates
COOP = ("coop.gnss_only", "coop.one_shot", "coop.iterated", "coop.centralized")
NETWORK = dict(latency=0.005, jitter=0.002, loss_prob=0.01, nlos_loss=0.1, max_range=100.0, round_s=0.01)
# per scenario: the [[estimators]] of the run, after the default estimators of its [pipeline] kind
# (testbed.plugins.defaults; built-ins with no params resolve theirs from the scenario's [pipeline]),
# and the keys of those a bag export cannot carry (no phase, no camera topic)
CASES = {
    "coop-fg": ([EstimatorSpec(entry=UWB_EKF), EstimatorSpec(entry=ECHO)], ()),
    # with a [network]: one_shot and iterated broadcast through Context.channel, in the run and on replay
    "coop-fg+network": ([EstimatorSpec(entry=ECHO)], ()),
    "bandwidth": ([EstimatorSpec(entry="testbed.replay.graph:PoseGraph"), EstimatorSpec(entry=ECHO)], ()),
    "phase-line-h000": ([EstimatorSpec(entry=ECHO)], ("ekf",)),  # its default: phase.ekf
    "visnav": ([EstimatorSpec(entry=ECHO)], ("ekf", "ckf", "hckf", "mckf", "rhcf")),  # its defaults: visnav.*
    "coop-denied": ([EstimatorSpec(entry="coop.ins_distributed", name="coop", params={"network": NETWORK}),
                     EstimatorSpec(entry=UWB_EKF), EstimatorSpec(entry=ECHO)], ()),
}
NOTE = re.compile(r"testbed: note: \S+: (\S+) is not exported: (.+)")


@pytest.fixture(scope="module", params=list(CASES))
def exported(request, tmp_path_factory):
    """(scenario name, the run's scenario, directory, export's stderr): a 2 s run with the case's
    estimators, exported to DIR/data and replayed with no options to DIR/rep."""
    name = request.param
    d = tmp_path_factory.mktemp(name)
    base, _, network = name.partition("+")
    sc = dataclasses.replace(scenario.load(base, duration=2.0), estimators=tuple(CASES[name][0]),
                             **({"network": NetworkConfig(**NETWORK)} if network else {}))
    run(sc, d / "run", plots=False)
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["export", str(d / "run"), "--out", str(d / "data")]) == 0
    assert main(["replay", str(d / "data" / "spec.toml"), "--out", str(d / "rep"), "--no-plots"]) == 0
    return name, sc, d, err.getvalue()


def test_the_replay_of_an_export_gives_the_estimates_of_the_simulation(exported):
    name, sc, d, _ = exported
    sim, rep = load_tracks(d / "run" / ESTIMATES_FILE), load_tracks(d / "rep" / ESTIMATES_FILE)
    assert set(sim) == {s.key for s in estimator_specs(sc)}  # each gave estimates in the run
    assert set(rep) == set(sim)
    for key in rep:
        assert rep[key].keys() == sim[key].keys()
        for tq, s in sim[key].items():
            r = rep[key][tq]
            assert r.time.shape == s.time.shape and s.time.size > 0, (key, tq)
            np.testing.assert_allclose(r.time, s.time, rtol=0, atol=1e-9, err_msg=f"{key} {tq}")
            np.testing.assert_allclose(r.value, s.value, rtol=0, atol=1e-9, err_msg=f"{key} {tq}")
            np.testing.assert_array_equal(r.has_cov, s.has_cov)
            np.testing.assert_allclose(r.cov, s.cov, rtol=1e-9, atol=1e-15, err_msg=f"{key} {tq}")
    # and the same scores against the exported truth (visnav's relative to the leader among them);
    # the run's scoring hooks (testbed.plugins.hooks: e.g. coop-fg's per-vehicle RMSE) are built
    # from its scenario, which a replay does not have: their keys are the run's only
    ran, replayed = (json.loads((d / k / "metrics.json").read_text())["estimators"] for k in ("run", "rep"))
    used = {key for key in rep if "network" in ran[key]}
    networked = {s.key for s in estimator_specs(sc) if s.entry in ("coop.one_shot", "coop.iterated")}
    assert used == (networked if sc.network is not None else set())
    for key in used:  # the same network, the same messages
        assert replayed[key]["network"] == ran[key]["network"], key
    for key in rep:
        scores = {k: v for k, v in ran[key].items() if k.split("_")[0] in ("rmse", "anees", "coverage")
                  and k in replayed[key]}
        assert "rmse_position_m" in scores or "rmse_velocity_m_s" in scores, key
        for k, v in scores.items():
            if v is None or isinstance(v, str):  # an interval not decidable from one run, and its reason
                assert replayed[key][k] == v, (key, k)
            else:
                np.testing.assert_allclose(replayed[key][k], v, rtol=1e-9, atol=1e-12, err_msg=f"{key} {k}")


def _left_out(notes: str, spec: Path, keys: set[str]) -> dict[str, str]:
    """{key: why} of the estimators an export's notes say it left out; checks that each has its
    comment line in the spec and that the spec lists all the others of `keys`."""
    said = dict(m.groups() for m in map(NOTE.fullmatch, notes.splitlines()) if m)
    assert sorted(line for line in spec.read_text().splitlines() if line.startswith("# ")) == \
        sorted(f"# {key} is not exported: {why}" for key, why in said.items())
    assert {s.key for s in load_spec(spec).estimators} == keys - set(said)
    return said


def test_a_csv_export_lists_every_estimator_of_the_run(exported):
    name, sc, d, notes = exported
    assert _left_out(notes, d / "data" / "spec.toml", {s.key for s in estimator_specs(sc)}) == {}


def test_a_bag_export_names_each_estimator_its_bag_cannot_drive(exported, tmp_path, capsys):
    """A bag has no phase and no camera topic: phase.ekf and visnav.* are left out of its spec, one
    note line and one comment line each saying why."""
    name, sc, d, _ = exported
    pytest.importorskip("rosbags")
    assert main(["export", str(d / "run"), "--out", str(tmp_path / "bag"), "--format", "mcap"]) == 0
    said = _left_out(capsys.readouterr().err, tmp_path / "bag" / "spec.toml", {s.key for s in estimator_specs(sc)})
    assert set(said) == set(CASES[name][1])
    stream = "phase" if name.startswith("phase") else "camera"
    assert all(f"the {stream} stream" in why and "a bag export does not carry" in why for why in said.values())


def _plain(x):
    """A sensors table as TOML gives it back (tuples as lists)."""
    return json.loads(json.dumps(x))


def test_the_replay_gives_each_estimator_the_context_it_had_in_the_simulation(exported):
    """Every Context field but `pipeline` (empty on replay: the exported built-ins carry their
    resolved params) equal to the simulation's; the rng the same stream (its first draws)."""
    _, sc, d, _ = exported
    rec = load_recording(d / "data" / "spec.toml")
    physics, prior = world.build(sc), priors(sc, load_run(d / "run").log)
    for s in rec.spec.estimators:
        a, b = make_context(sc, lever_arms(physics), s.key, s.params, prior), rec.context(s.key, s.params)
        assert (a.vehicles, a.duration, a.motion, a.seed, a.params) == (b.vehicles, b.duration, b.motion, b.seed, b.params)
        assert a.sites.keys() == b.sites.keys() and a.anchors.keys() == b.anchors.keys() and a.prior.keys() == b.prior.keys()
        for site, (body, arm) in a.sites.items():
            assert b.sites[site][0] == body and np.array_equal(b.sites[site][1], arm)
        assert all(np.array_equal(b.anchors[k], p) for k, p in a.anchors.items())
        assert all(np.array_equal(b.prior[k][0], m) and np.array_equal(b.prior[k][1], c) for k, (m, c) in a.prior.items())
        assert _plain(b.sensors) == _plain(a.sensors)
        assert np.array_equal(a.rng.standard_normal(4), b.rng.standard_normal(4))
    assert bool(prior) == (sc.pipeline.kind in ("phase-ekf", "visnav", "bandwidth") if sc.pipeline else False)


def test_the_export_lists_the_default_estimators_with_the_params_they_ran_with():
    """A coop-fg run without [[estimators]]: the four default estimators of its [pipeline] kind
    (testbed.plugins.defaults) under their metrics names, each with every key of the scenario's
    [pipeline] (the assumed ds-twr ranging and 0.035 m antenna delays among them); with
    [[estimators]], those follow, and a key given in params wins."""
    sc = scenario.load("coop-fg", duration=2.0)
    physics = world.build(sc)
    table = {k: v for k, v in to_dict(sc.pipeline).items() if k != "kind"}
    defaults = [(s.key, s.entry) for s in default_specs(sc)]
    assert defaults == [(e.partition(".")[2], e) for e in COOP]
    specs, skipped = exported_estimators(dataclasses.replace(sc, estimators=()), physics, priors(sc, None))
    assert [(s.key, s.entry) for s in specs] == defaults and not skipped
    assert all(s.params == table for s in specs)
    assert (table["twr_mode"], table["antenna_delay_sigma"]) == ("ds-twr", 0.035)
    own = EstimatorSpec(entry="coop.centralized", name="huber", params={"robust": "huber"})
    specs, _ = exported_estimators(dataclasses.replace(sc, estimators=(own,)), physics, priors(sc, None))
    assert [s.key for s in specs] == [k for k, _ in defaults] + ["huber"]
    assert specs[-1].params == {**table, "robust": "huber"}


SPEC = "[window]\nend = 1.0\n[bodies.uav1.sites]\ncam = [0.0, 0.0, 0.0]\nled1 = [0.1, 0.0, 0.0]\n[anchors]\nanchor1 = [0.0, 0.0, 2.0]\n"


def _refused(tmp_path, capsys, files: dict[str, str]) -> tuple[Path, str]:
    """(the dataset directory, the one error line) of a replay of a dataset of these files and an
    empty links.csv; asserts exit 2 and nothing written."""
    d = tmp_path / "data"
    d.mkdir()
    for name, text in {"links.csv": "time,src,dst,kind,value\n", **files}.items():
        (d / name).write_text(text)
    assert main(["replay", str(d / "spec.toml"), "--out", str(tmp_path / "o"), "--estimator", ECHO]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and not (tmp_path / "o").exists(), err
    return d, err


@pytest.mark.parametrize("prior, key", [
    ("mean = [1.0, 2.0]\ncov = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]", "prior.uav1.cov"),
    ("mean = [1.0, 2.0]\ncov = [[1.0, 0.0], [0.0]]", "prior.uav1.cov"),
    ("mean = []\ncov = []", "prior.uav1.mean"),
    ("mean = [1.0, nan]\ncov = [[1.0]]", "prior.uav1.mean"),
    ("mean = [1.0]", "prior.uav1"),
])
def test_a_bad_prior_is_one_line_naming_its_key(tmp_path, capsys, prior, key):
    d, err = _refused(tmp_path, capsys, {"spec.toml": f"{SPEC}[prior.uav1]\n{prior}\n"})
    assert err.startswith(f"testbed: error: {d / 'spec.toml'}: {key}: "), err


def test_a_bad_nlos_flag_is_one_line_naming_its_file_row_and_column(tmp_path, capsys):
    d, err = _refused(tmp_path, capsys, {"spec.toml": SPEC, "links.csv": "time,src,dst,kind,value,nlos\n"
                                         "0.0,uav1/cam,anchor1,uwb,2.0,0\n0.1,uav1/cam,anchor1,uwb,2.0,0.5\n"})
    assert err.startswith(f"testbed: error: {d / 'links.csv'}") and "nlos" in err and "0.5" in err, err


def test_a_network_without_truth_is_one_line(tmp_path, capsys):
    d, err = _refused(tmp_path, capsys, {"spec.toml": f"{SPEC}[network]\nlatency = 0.005\n",
                                         "links.csv": "time,src,dst,kind,value\n0.0,uav1/cam,anchor1,uwb,2.0\n"})
    assert err == f"testbed: error: {d / 'spec.toml'}: network: the network's geometry is the true one, so it " \
                  "needs the truth table (truth.csv): add it or remove [network]", err


@pytest.mark.parametrize("row, column", [
    ("0.0,uav1/cam,uav9/led1,0.1,0.0,0.1,0.0,-0.99", "dst"),
    ("0.0,anchor1,uav1/led1,0.1,0.0,0.1,0.0,-0.99", "src"),
    ("0.0,uav1/cam,uav1/led1,0.1,,0.1,0.0,-0.99", "beta"),
])
def test_a_bad_camera_row_is_one_line_naming_its_file_row_and_column(tmp_path, capsys, row, column):
    d, err = _refused(tmp_path, capsys, {"spec.toml": SPEC, "camera.csv": f"time,src,dst,alpha,beta,bx,by,bz\n{row}\n"})
    assert err.startswith(f"testbed: error: {d / 'camera.csv'}: row 1 (line 2), column {column}: "), err


PHASE_HEADER = ("time,src,dst,phase,range,master_x,master_y,master_z,master_vx,master_vy,master_vz,"
                "rate_periods,wavelength,slip\n")


@pytest.mark.parametrize("cells, column", [
    ("1.0,10.0,0,0,0,0,0,0,2,0.19,2", "slip"),
    ("1.0,10.0,0,0,0,0,0,0,-1,0.19,0", "rate_periods"),
    ("1.0,10.0,0,0,0,0,0,0,1.5,0.19,0", "rate_periods"),
    ("1.0,10.0,0,0,0,0,0,0,1,0,0", "wavelength"),
    ("1.0,,0,0,0,0,0,0,1,0.19,0", "range"),
])
def test_a_bad_phase_row_is_one_line_naming_its_file_row_and_column(tmp_path, capsys, cells, column):
    d, err = _refused(tmp_path, capsys, {"spec.toml": SPEC, "phase.csv": f"{PHASE_HEADER}0.0,uav1/cam,uav1/led1,{cells}\n"})
    assert err.startswith(f"testbed: error: {d / 'phase.csv'}: row 1 (line 2), column {column}: "), err


def test_the_phase_stream_from_two_tables_is_refused(tmp_path, capsys):
    links = "time,src,dst,kind,value\n0.0,uav1/cam,anchor1,phase,2.0\n"
    phase = f"{PHASE_HEADER}0.0,uav1/cam,uav1/led1,1.0,10.0,0,0,0,0,0,0,1,0.19,0\n"
    d, err = _refused(tmp_path, capsys, {"spec.toml": SPEC, "links.csv": links, "phase.csv": phase})
    assert err.startswith(f"testbed: error: {d / 'phase.csv'}: row 1 (line 2), column phase: ") and "links.csv" in err, err
