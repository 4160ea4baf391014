"""Never lose a user's data: every refused output location, each with a sentinel that must survive.

The testbed only replaces a directory it can prove it wrote (its `.testbed` marker); everything else
is refused with one line `testbed: error: ...` and exit code 2, `--force` or not, and nothing is
left behind (no temporary sibling, no lock file).
"""
import json
import math
import shutil
from pathlib import Path

import pytest

from testbed import outdir
from testbed.cli import main

RUN = ["run", "bandwidth", "--duration", "0.5", "--no-plots"]  # no test here looks at figures


def _refused(capsys, argv: list[str]) -> str:
    """Run the CLI in-process; assert exit 2 with exactly one stderr line; return it."""
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("testbed: error: "), err
    return lines[0]


def _no_debris(parent: Path) -> None:
    left = [p.name for p in parent.iterdir() if ".testbed-" in p.name]
    assert not left, left


def _sentinel(d: Path) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    s = d / "my-thesis.tex"
    s.write_text("years of work\n")
    return s


def _intact(s: Path) -> None:
    assert s.read_text() == "years of work\n"


@pytest.fixture
def cwd(tmp_path, monkeypatch) -> Path:
    work = tmp_path / "home" / "work"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    return work


@pytest.mark.parametrize("force", [[], ["--force"]])
@pytest.mark.parametrize("where", [".", "..", "HOME", "/", "./"])
def test_working_directory_its_parents_home_and_root_are_refused(capsys, cwd, where, force):
    s_here, s_home = _sentinel(cwd), _sentinel(cwd.parent)
    target = str(cwd.parent) if where == "HOME" else where
    msg = _refused(capsys, RUN + ["--out", target] + force)
    assert target.rstrip("/") in msg or "working directory" in msg
    _intact(s_here), _intact(s_home)
    _no_debris(cwd), _no_debris(cwd.parent)


@pytest.mark.parametrize("cmd", [RUN, ["sweep", "bandwidth", "--runs", "2"], ["reproduce", "phase"], ["demo"]])
def test_empty_string_is_refused(capsys, cwd, cmd):
    s = _sentinel(cwd)
    assert "empty path" in _refused(capsys, cmd + ["--out", "", "--force"])
    _intact(s)
    assert sorted(p.name for p in cwd.iterdir()) == [s.name]


@pytest.mark.parametrize("cmd", [
    RUN, RUN + ["--force"],
    ["sweep", "bandwidth", "--runs", "2"], ["sweep", "bandwidth", "--runs", "2", "--force"],
    ["sweep", "bandwidth", "--runs", "2", "--resume"],
    ["reproduce", "phase"], ["reproduce", "phase", "--force"],
    ["demo"], ["demo", "--force"],
])
def test_non_empty_directory_without_marker_is_refused(capsys, cwd, cmd):
    s = _sentinel(cwd / "results")
    msg = _refused(capsys, cmd + ["--out", "results"])
    assert "results" in msg and "not written by the testbed" in msg
    _intact(s)
    assert sorted(p.name for p in (cwd / "results").iterdir()) == [s.name]
    _no_debris(cwd)


@pytest.mark.parametrize("force", [[], ["--force"]])
def test_a_file_and_a_path_under_a_file_are_refused(capsys, cwd, force):
    s = _sentinel(cwd)
    assert "not a directory" in _refused(capsys, RUN + ["--out", s.name] + force)
    assert "is a file" in _refused(capsys, RUN + ["--out", f"{s.name}/run"] + force)
    _intact(s)
    _no_debris(cwd)


def test_symlink_is_refused_and_its_target_kept(capsys, cwd):
    target = cwd / "elsewhere"
    target.mkdir()
    outdir.write_marker(target, "run")
    s = _sentinel(target)
    (cwd / "link").symlink_to(target)
    assert "symbolic link" in _refused(capsys, RUN + ["--out", "link", "--force"])
    _intact(s)
    assert (cwd / "link").is_symlink()


def test_earlier_output_needs_force_and_is_then_replaced(capsys, cwd):
    assert main(RUN + ["--out", "r"]) == 0
    marker = json.loads((cwd / "r" / ".testbed").read_text())
    assert marker["written_by"] == "testbed" and marker["kind"] == "run" and marker["version"]
    metrics = (cwd / "r" / "metrics.json").read_bytes()
    (cwd / "r" / "note.txt").write_text("mine")
    capsys.readouterr()
    assert "use --force" in _refused(capsys, RUN + ["--out", "r"])
    assert (cwd / "r" / "note.txt").read_text() == "mine"
    assert main(RUN + ["--out", "r", "--force"]) == 0
    assert not (cwd / "r" / "note.txt").exists() and (cwd / "r" / "metrics.json").read_bytes() == metrics
    _no_debris(cwd)


def test_empty_directory_is_used(capsys, cwd):
    (cwd / "r").mkdir()
    assert main(RUN + ["--out", "r"]) == 0
    assert (cwd / "r" / ".testbed").is_file() and (cwd / "r" / "log.npz").is_file()
    _no_debris(cwd)


def test_demo_refuses_another_testbed_output_without_force(capsys, cwd):
    assert main(RUN + ["--out", "r"]) == 0
    capsys.readouterr()
    before = sorted(p.name for p in (cwd / "r").iterdir())
    assert "use --force" in _refused(capsys, ["demo", "--out", "r"])
    assert sorted(p.name for p in (cwd / "r").iterdir()) == before


def _fake_run_dir(d: Path) -> None:
    d.mkdir()
    (d / "scene.xml").write_text("<mujoco/>")
    (d / "log.npz").write_bytes(b"")


def test_render_refuses_to_overwrite_a_file(capsys, cwd):
    _fake_run_dir(cwd / "r")
    s = _sentinel(cwd)
    assert "use --force" in _refused(capsys, ["render", "r", "--out", s.name])
    (cwd / "r" / "video.mp4").write_text("years of work\n")
    assert "use --force" in _refused(capsys, ["render", "r"])
    _intact(s), _intact(cwd / "r" / "video.mp4")
    assert "is a directory" in _refused(capsys, ["render", "r", "--out", "r", "--force"])
    _no_debris(cwd)


def test_render_force_replaces_the_file_atomically(capsys, cwd):
    assert main(RUN + ["--out", "r"]) == 0
    (cwd / "v.mp4").write_text("old")
    assert main(["render", "r", "--out", "v.mp4", "--width", "64", "--height", "48", "--fps", "5", "--max-seconds", "0.4"]) == 2
    assert (cwd / "v.mp4").read_text() == "old"
    assert main(["render", "r", "--out", "v.mp4", "--force", "--width", "64", "--height", "48", "--fps", "5", "--max-seconds", "0.4"]) == 0
    assert (cwd / "v.mp4").read_bytes()[4:8] == b"ftyp"
    _no_debris(cwd)


def test_stale_temporary_directory_of_a_dead_process_is_removed_and_an_old_output_restored(capsys, cwd):
    dead = 2**22 + 12345  # above pid_max's default: no such process
    assert not outdir._pid_alive(dead)
    (cwd / f".r{outdir.TMP_TAG}{dead}").mkdir()
    live = cwd / f".r{outdir.TMP_TAG}1"  # pid 1 is alive: not touched
    live.mkdir()
    old = cwd / f".r{outdir.OLD_TAG}{dead}"
    old.mkdir()
    outdir.write_marker(old, "run")
    s = _sentinel(old)
    outdir.clean_stale(cwd / "r")
    assert not (cwd / f".r{outdir.TMP_TAG}{dead}").exists() and live.is_dir()
    _intact(cwd / "r" / s.name)  # the old output, set aside by a killed replacement, is back


def test_metrics_are_strict_json_and_a_missing_score_is_null_with_a_reason(tmp_path):
    from testbed.config import scenario
    from testbed.runner import run

    with pytest.raises(ValueError, match=r"a\.b\[1\]"):
        outdir.write_json(tmp_path / "x.json", {"a": {"b": [1.0, math.nan]}})
    assert not (tmp_path / "x.json").exists()
    sc = scenario.load("coop-fg", {"trajectory.rtk": "[]"}, duration=1.0)
    run(sc, tmp_path / "r", plots=False)

    def no_constant(name):
        raise AssertionError(f"bare {name} in metrics.json")

    m = json.loads((tmp_path / "r" / "metrics.json").read_text(), parse_constant=no_constant)
    for est in m["estimators"].values():
        assert est["rmse_position_rtk_mean_m"] is None and est["anees_rtk"] is None
        assert est["null_reasons"] == {"rmse_position_rtk_mean_m": "no RTK vehicle in this scenario",
                                       "anees_rtk": "no RTK vehicle in this scenario",
                                       "n_eff_rtk": "no RTK vehicle in this scenario"}
        assert isinstance(est["rmse_position_spp_mean_m"], float) and "rmse_position_spp_mean_m" not in est["null_reasons"]


# ----------------------------------------------------------- --out never overlaps an input

PLUGIN = "class Quiet:\n    def __init__(self, context, params):\n        pass\n\n    def process(self, m):\n        return []\n"


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    """A run directory `r` (bandwidth, 0.5 s) and its export `data` (a dataset with the marker)."""
    root = tmp_path_factory.mktemp("inputs")
    from testbed.config import scenario
    from testbed.replay.export import export
    from testbed.runner import run

    run(scenario.load("bandwidth", duration=0.5), root / "r", plots=False)
    export(root / "r", root / "data")
    return root


def _files(d: Path) -> dict[str, bytes]:
    return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def _in_marked(cwd: Path, name: str, inner: str) -> Path:
    """A directory `name` the testbed wrote (marker) holding `inner` (a copy of the run or a file)."""
    d = cwd / name
    d.mkdir()
    outdir.write_marker(d, "run")
    return d / inner


@pytest.mark.parametrize("case", [
    "replay-out-is-the-dataset", "replay-out-is-a-table", "replay-out-is-the-dataset-through-a-link",
    "export-out-is-the-run", "export-out-inside-the-run", "export-out-contains-the-run",
    "render-out-is-the-log", "run-out-contains-the-scenario", "sweep-out-contains-the-scenario",
    "run-out-contains-the-estimator", "reproduce-out-contains-the-estimator", "replay-out-contains-the-estimator",
])
def test_out_that_is_contains_or_lies_inside_an_input_is_refused(capsys, cwd, inputs, case):
    """`--out` equal to, above or below any input (resolved: relative paths, symbolic links) is one
    line and exit 2, --force or not; every input is left as it was."""
    from importlib import resources

    shutil.copytree(inputs / "r", cwd / "r")
    shutil.copytree(inputs / "data", cwd / "data")
    if case.endswith("-scenario"):
        _in_marked(cwd, "d", "s.toml").write_bytes((resources.files("testbed.scenarios") / "bandwidth.toml").read_bytes())
    if case.endswith("-estimator"):
        _in_marked(cwd, "d", "plug.py").write_text(PLUGIN)
    if case == "export-out-contains-the-run":  # the run inside an earlier output of the testbed
        shutil.copytree(cwd / "r", _in_marked(cwd, "d", "r"))
    (cwd / "alias").symlink_to(cwd / "data")
    argv = {
        "replay-out-is-the-dataset": ["replay", "data/spec.toml", "--estimator", "graph.poses", "--out", "data"],
        "replay-out-is-a-table": ["replay", "data/spec.toml", "--estimator", "graph.poses", "--out", "data/links.csv"],
        "replay-out-is-the-dataset-through-a-link": ["replay", "alias/spec.toml", "--estimator", "graph.poses", "--out", "./data/"],
        "export-out-is-the-run": ["export", "r", "--out", "r"],
        "export-out-inside-the-run": ["export", "r", "--out", "r/dataset"],
        "export-out-contains-the-run": ["export", "d/r", "--out", "d"],
        "render-out-is-the-log": ["render", "r", "--out", "r/log.npz"],
        "run-out-contains-the-scenario": ["run", "d/s.toml", "--out", "d"],
        "sweep-out-contains-the-scenario": ["sweep", "d/s.toml", "--runs", "2", "--out", "d"],
        "run-out-contains-the-estimator": RUN + ["--estimator", "d/plug.py:Quiet", "--out", "d"],
        "reproduce-out-contains-the-estimator": ["reproduce", "phase", "--estimator", "d/plug.py:Quiet", "--out", "d"],
        "replay-out-contains-the-estimator": ["replay", "data/spec.toml", "--estimator", "d/plug.py:Quiet", "--out", "d"],
    }[case]
    before = {p.name: _files(p) for p in cwd.iterdir() if p.is_dir() and not p.is_symlink()}
    msg = _refused(capsys, argv + ["--force"])
    assert f"--out {Path(argv[argv.index('--out') + 1])}: " in msg and " the input " in msg, msg
    assert {p.name: _files(p) for p in cwd.iterdir() if p.is_dir() and not p.is_symlink()} == before
    _no_debris(cwd)


def test_a_replay_may_write_beside_its_dataset_files_and_leaves_them_as_they_were(cwd, inputs):
    """The inputs of a replay are the files it reads (the spec, its tables or bag), not the folder
    they lie in: replaying from inside a dataset folder into a new folder there is allowed."""
    shutil.copytree(inputs / "data", cwd / "data")
    before = _files(cwd / "data")
    assert main(["replay", "data/spec.toml", "--estimator", "graph.poses", "--out", "data/replay", "--no-plots"]) == 0
    assert {k: v for k, v in _files(cwd / "data").items() if not k.startswith("replay/")} == before
    assert (cwd / "data" / "replay" / "metrics.json").is_file()


def test_unheld_lock_files_are_removed_and_held_ones_kept(tmp_path):
    """After an interrupted Ray sweep, a run's lock whose task was killed before releasing it is
    removed by the sweep (outdir.remove_unheld_locks) with the run's temporary directory; a lock a
    live writer holds stays, with its temporary directory, also after waiting for it."""
    from testbed.outdir import LOCK_TAG, TMP_TAG, Lock, remove_unheld_locks

    held = Lock(tmp_path / "run-000")
    held.acquire()
    (tmp_path / f".run-000{TMP_TAG}123").mkdir()
    (tmp_path / f".run-001{LOCK_TAG}").write_text("pid 1 (killed)\n")
    (tmp_path / f".run-001{TMP_TAG}456").mkdir()
    (tmp_path / f".run-001{TMP_TAG}456" / "log.npz").write_bytes(b"partial")
    remove_unheld_locks(tmp_path, wait_s=0.2)
    assert sorted(p.name for p in tmp_path.iterdir()) == [f".run-000{LOCK_TAG}", f".run-000{TMP_TAG}123"]
    (tmp_path / f".run-000{TMP_TAG}123").rmdir()
    held.release()
    assert list(tmp_path.iterdir()) == []
