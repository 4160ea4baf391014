"""Faults: signals mid-run and mid-sweep, killed parents, concurrent writers, full and read-only disks,
closed pipes. Every case ends in one line and a known exit code, with nothing half-written left.

The command under fault runs as a subprocess (`python -m testbed`, this checkout first on
PYTHONPATH) in a temporary working directory; a command that only prepares a case or follows it
(the run to render, the next command after a kill, an uninterrupted reference) runs in this
process (`testbed.cli.main`), which saves an interpreter start. Short bandwidth runs keep each
case to seconds.
"""
import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from testbed.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": str(ROOT)}


def _start(cwd: Path, *args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "testbed", *args], cwd=cwd, env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _testbed(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "testbed", *args], cwd=cwd, env=_env(), capture_output=True, text=True, timeout=300)


def _wait_for(cond, what: str, timeout: float = 120.0) -> None:
    t0 = time.monotonic()
    while not cond():
        assert time.monotonic() - t0 < timeout, f"timed out waiting for {what}"
        time.sleep(0.05)


def _stat(pid: int) -> tuple[str, int] | None:
    """(state, ppid) of a live process, None if it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()
    return fields[0], int(fields[1])


def _children(pid: int) -> list[int]:
    out = []
    for p in Path("/proc").iterdir():
        if p.name.isdigit() and (st := _stat(int(p.name))) is not None and st[1] == pid:
            out.append(int(p.name))
    return out


def _workers(pid: int) -> list[int]:
    """The pool workers among the children of `pid` (not multiprocessing's resource tracker, which
    exits with its parent)."""
    def cmdline(c: int) -> bytes:
        try:
            return Path(f"/proc/{c}/cmdline").read_bytes()
        except OSError:
            return b""
    return [c for c in _children(pid) if b"multiprocessing.spawn" in cmdline(c)]


def _gone(pids: list[int]) -> bool:
    return all((st := _stat(p)) is None or st[0] in "ZX" for p in pids)


def _debris(root: Path) -> list[str]:
    return [str(p.relative_to(root)) for p in root.rglob("*") if ".testbed-" in p.name]


def _tmp_dirs(cwd: Path, name: str) -> list[Path]:
    return [p for p in cwd.glob(f".{name}.testbed-tmp.*") if p.is_dir()]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_signal_mid_run_removes_the_temporary_directory(tmp_path, sig):
    # 3600 s of bandwidth takes far longer than the 0.5 s below on any machine (60 s took about 1 s
    # on an idle one: the signal then landed in the interpreter's exit, a flaky exit code)
    p = _start(tmp_path, "run", "bandwidth", "--duration", "3600", "--out", "r")
    _wait_for(lambda: _tmp_dirs(tmp_path, "r"), "the run's temporary directory")
    time.sleep(0.5)  # inside the simulation
    p.send_signal(sig)
    _, err = p.communicate(timeout=30)
    assert p.returncode == 128 + sig
    assert err.splitlines() == [f"testbed: run bandwidth interrupted by {sig.name}: temporary files removed"]
    assert sorted(os.listdir(tmp_path)) == []


def test_sigkill_leaves_only_a_temporary_directory_that_the_next_command_cleans(tmp_path, monkeypatch, capsys):
    p = _start(tmp_path, "run", "bandwidth", "--duration", "3600", "--out", "r")
    _wait_for(lambda: _tmp_dirs(tmp_path, "r"), "the run's temporary directory")
    stale = _tmp_dirs(tmp_path, "r")[0]
    p.kill()
    p.communicate()
    assert not (tmp_path / "r").exists()
    assert all(n.startswith(".r.testbed-") for n in os.listdir(tmp_path))
    assert stale.name.endswith(str(p.pid))  # recognisable: it names the dead writer
    monkeypatch.chdir(tmp_path)  # the next command, in this process (the killed one was a real one)
    capsys.readouterr()
    assert main(["run", "bandwidth", "--duration", "0.5", "--out", "r", "--no-plots"]) == 0
    assert capsys.readouterr().err.splitlines() == [f"testbed: removed {stale.name} (left by pid {p.pid}, which died)"]
    assert sorted(os.listdir(tmp_path)) == ["r"] and _debris(tmp_path) == []


def _sweep_args(out: str, workers: int = 2) -> list[str]:
    # without figures (no test here looks at them); a run of 10 s (~0.3 s CPU) still spans several
    # polls of _wait_for, so the SIGINT lands before the last run finishes
    return ["sweep", "bandwidth", "--runs", "4", "--workers", str(workers), "--duration", "10", "--out", out, "--no-plots"]


@pytest.mark.slow  # three sweeps of four runs without figures
def test_interrupted_sweep_stops_workers_keeps_finished_runs_and_resumes_byte_identical(tmp_path, monkeypatch):
    p = _start(tmp_path, *_sweep_args("sw"))
    _wait_for(lambda: any((d / "metrics.json").is_file() for t in _tmp_dirs(tmp_path, "sw") for d in t.glob("run-*")),
              "a finished run")
    workers = _workers(p.pid)
    assert len(workers) >= 2
    p.send_signal(signal.SIGINT)
    t0 = time.monotonic()
    _wait_for(lambda: _gone(workers), "the workers to stop", timeout=5.0)
    assert time.monotonic() - t0 < 5.0
    _, err = p.communicate(timeout=30)
    assert p.returncode == 130
    done = sorted(d.name for d in (tmp_path / "sw").glob("run-*"))
    assert 1 <= len(done) < 4
    assert err.splitlines()[-1] == (f"testbed: sweep bandwidth interrupted by SIGINT: {len(done)} of 4 runs kept in sw "
                                    "(summary.json marked incomplete; continue with --resume)")
    summary = json.loads((tmp_path / "sw" / "summary.json").read_text())
    assert summary["incomplete"] is True and summary["runs_done"] == len(done)
    assert not (tmp_path / "sw" / "summary.csv").exists()
    assert _debris(tmp_path) == []
    before = {d: (tmp_path / "sw" / d / "log.npz").stat().st_mtime_ns for d in done}

    q = _testbed(tmp_path, *_sweep_args("sw"), "--resume")
    assert q.returncode == 0, q.stderr
    assert {d: (tmp_path / "sw" / d / "log.npz").stat().st_mtime_ns for d in done} == before  # finished runs not redone
    # the uninterrupted reference, in this process and its runs one after the other (no worker to
    # start; the bytes do not depend on the number of workers)
    monkeypatch.chdir(tmp_path)
    assert main(_sweep_args("whole", workers=1)) == 0
    for f in ["summary.json", "summary.csv", "sweep.toml", *(f"run-{i:03d}/metrics.json" for i in range(4))]:
        assert (tmp_path / "sw" / f).read_bytes() == (tmp_path / "whole" / f).read_bytes(), f
    assert _debris(tmp_path) == []


@pytest.mark.parametrize("cmd", [["reproduce", "phase", "--runs", "2", "--duration", "1", "--workers", "2"], ["demo"]])
def test_sigterm_mid_reproduce_or_demo_removes_everything_and_stops_workers(tmp_path, cmd):
    p = _start(tmp_path, *cmd, "--out", "o")
    _wait_for(lambda: any(t.glob(".*.testbed-tmp.*") for t in _tmp_dirs(tmp_path, "o")), "a run inside the output")
    time.sleep(0.5)
    workers = _children(p.pid)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=30)
    assert p.returncode == 128 + signal.SIGTERM
    line = err.splitlines()[-1]
    assert line.startswith(f"testbed: {' '.join(cmd[:2])} interrupted by SIGTERM: ") and "kept in" not in line, line
    _wait_for(lambda: _gone(workers), "the workers to stop", timeout=5.0)
    assert os.listdir(tmp_path) == []


def _reproduce_args(out: str) -> list[str]:
    # the runs without figures (--no-run-plots): their simulation and scoring, ~0.5 s CPU each
    return ["reproduce", "coop", "--runs", "3", "--workers", "2", "--duration", "2", "--out", out, "--no-run-plots"]


def _finished_runs(root: Path) -> list[Path]:
    return [d for d in root.rglob("run-*") if (d / "metrics.json").is_file()]


def _tree(root: Path) -> dict[str, bytes]:
    """Every file's bytes but provenance.json's and timing.json's (when and how it was made, the wall
    times: never the same twice)."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.name not in ("provenance.json", "timing.json")}


@pytest.mark.slow  # three short coop reproductions, ~4 min on a loaded 2-core machine
def test_interrupted_reproduce_keeps_finished_runs_and_resumes_byte_identical(tmp_path, monkeypatch):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    p = _start(tmp_path / "a", *_reproduce_args("rp"))
    _wait_for(lambda: any(_finished_runs(t) for t in _tmp_dirs(tmp_path / "a", "rp")), "a finished run", timeout=300)
    workers = _workers(p.pid)
    p.send_signal(signal.SIGINT)
    t0 = time.monotonic()
    _wait_for(lambda: _gone(workers), "the workers to stop", timeout=5.0)
    assert time.monotonic() - t0 < 5.0
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130, err
    rp = tmp_path / "a" / "rp"
    done = sorted(str(d.relative_to(rp)) for d in _finished_runs(rp))
    assert 1 <= len(done) < 3
    assert err.splitlines()[-1] == (f"testbed: reproduce coop interrupted by SIGINT: {len(done)} runs kept in rp "
                                    "(summary.json marked incomplete; continue with --resume)")
    summary = json.loads((rp / "summary.json").read_text())
    assert summary["incomplete"] is True and summary["runs_done"] == len(done)
    assert _debris(tmp_path) == []
    before = {d: (rp / d / "log.npz").stat().st_mtime_ns for d in done}

    q = _testbed(tmp_path / "a", *_reproduce_args("rp"), "--resume")
    assert q.returncode == 0, q.stderr
    assert {d: (rp / d / "log.npz").stat().st_mtime_ns for d in done} == before  # finished runs not redone
    assert not (rp / "summary.json").exists()
    # the uninterrupted reference, in this process (the same command: its report shows it)
    monkeypatch.chdir(tmp_path / "b")
    assert main(_reproduce_args("rp")) == 0
    resumed, whole = _tree(rp), _tree(tmp_path / "b" / "rp")
    assert sorted(resumed) == sorted(whole)
    assert not any(f.endswith(".png") and f.startswith("runs/") for f in whole)  # --no-run-plots
    assert "--no-run-plots" in (rp / "report.md").read_text()  # the command that reproduces it
    assert [f for f in resumed if resumed[f] != whole[f]] == []
    assert _debris(tmp_path) == []


def _interrupted_reproduction(d: Path, options: dict) -> None:
    from testbed.outdir import write_json, write_marker

    d.mkdir()
    write_marker(d, "reproduce-coop")
    write_json(d / "summary.json", {"paper": "coop", "options": options, "incomplete": True, "runs_done": 1})


def test_reproduce_resume_refuses_other_options_and_a_complete_reproduction(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    _interrupted_reproduction(tmp_path / "rp", {"paper": "coop", "runs": 3, "motion": "prescribed", "duration": 2.0,
                                                "estimators": []})
    assert main(["reproduce", "coop", "--runs", "4", "--duration", "2", "--out", "rp", "--resume"]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("testbed: error: rp: was reproduced with other options (rp/summary.json: ") and "cannot resume" in line
    (tmp_path / "rp" / "summary.json").unlink()  # as a complete reproduction leaves it
    assert main(["reproduce", "coop", "--runs", "3", "--duration", "2", "--out", "rp", "--resume"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "testbed: error: rp: is not an interrupted reproduction (no incomplete summary.json); nothing to resume"]
    assert sorted(os.listdir(tmp_path / "rp")) == [".testbed"]


def test_sigint_mid_render_removes_the_partial_video(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["run", "bandwidth", "--duration", "2", "--out", "r", "--no-plots"]) == 0  # the run to render
    p = _start(tmp_path, "render", "r", "--width", "64", "--height", "48", "--speed", "0.01")
    _wait_for(lambda: list((tmp_path / "r").glob(".video.mp4.testbed-tmp.*")), "the partial video")
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=30)
    assert p.returncode == 130 and err.splitlines()[-1] == "testbed: render r interrupted by SIGINT: temporary files removed"
    assert not (tmp_path / "r" / "video.mp4").exists() and _debris(tmp_path) == []


def test_resume_refuses_a_different_scenario(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["sweep", "bandwidth", "--runs", "1", "--duration", "0.5", "--out", "sw", "--no-plots"]) == 0
    capsys.readouterr()
    assert main(["sweep", "bandwidth", "--runs", "2", "--duration", "0.6", "--out", "sw", "--resume"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "testbed: error: sw: was swept with a different scenario (sw/sweep.toml); cannot resume it with this one"]


def test_killing_the_sweep_parent_leaves_no_orphan_workers(tmp_path, monkeypatch):
    p = _start(tmp_path, "sweep", "bandwidth", "--runs", "4", "--workers", "2", "--duration", "30", "--out", "sw")
    _wait_for(lambda: any(t.glob(".run-*.testbed-tmp.*") for t in _tmp_dirs(tmp_path, "sw")), "a run in a worker")
    # the pool's processes (resource tracker + 2 workers) may still be starting: wait for them
    _wait_for(lambda: len(_children(p.pid)) >= 3, "the sweep's worker processes")
    workers = _children(p.pid)
    p.kill()
    p.communicate()
    t0 = time.monotonic()
    _wait_for(lambda: _gone(workers), "the orphaned workers to exit", timeout=5.0)
    assert time.monotonic() - t0 < 5.0
    assert not (tmp_path / "sw").exists()
    monkeypatch.chdir(tmp_path)  # the next sweep, in this process
    assert main(["sweep", "bandwidth", "--runs", "1", "--duration", "0.5", "--out", "sw", "--no-plots"]) == 0
    assert _debris(tmp_path) == []


def test_two_writers_of_one_output_exactly_one_wins(tmp_path, monkeypatch, capsys):
    # the first writer must still be writing when the second one starts (its own start-up takes
    # ~1.5 s): 8 s of bandwidth took ~2 s all told and once finished before it (a CI failure);
    # 600 s keeps it writing for several seconds (the test: 8.4 s)
    a = _start(tmp_path, "run", "bandwidth", "--duration", "600", "--out", "r", "--no-plots")
    _wait_for(lambda: (tmp_path / ".r.testbed-lock").is_file() and _tmp_dirs(tmp_path, "r"), "the first writer's lock")
    monkeypatch.chdir(tmp_path)  # the second writer, in this process
    capsys.readouterr()
    assert main(["run", "bandwidth", "--duration", "0.5", "--out", "r", "--force"]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("testbed: error: r: is being written by ") and f"pid {a.pid} (testbed run bandwidth --duration 600" in line
    a.communicate(timeout=120)
    assert a.returncode == 0
    assert json.loads((tmp_path / "r" / "metrics.json").read_text())["duration_s"] == 600.0
    assert sorted(os.listdir(tmp_path)) == ["r"]


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS, errno.EACCES])
def test_os_errors_while_writing_are_one_line_and_leave_nothing(tmp_path, monkeypatch, capsys, code):
    from testbed.log import LogWriter

    def failing_save(self, path):
        raise OSError(code, os.strerror(code), str(path))

    monkeypatch.setattr(LogWriter, "save", failing_save)  # the run's log.npz is written by LogWriter.save
    monkeypatch.chdir(tmp_path)
    assert main(["run", "bandwidth", "--duration", "0.5", "--out", "deep/r"]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line == f"testbed: error: deep/r: {os.strerror(code)} (deep/r/log.npz)"
    assert os.listdir(tmp_path) == []  # not even the parent it created


@pytest.fixture
def tmpfs(tmp_path):
    """mount(options) -> a small tmpfs under tmp_path (skips where mounting is not allowed)."""
    mounted = []

    def mount(options: str) -> Path:
        d = tmp_path / f"mnt{len(mounted)}"
        d.mkdir()
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(d)], capture_output=True)
        if r.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {r.stderr.decode().strip()} (the in-process ENOSPC/EROFS test covers it)")
        mounted.append(d)
        return d

    yield mount
    for d in mounted:
        subprocess.run(["umount", str(d)], check=False)


@pytest.mark.parametrize("cmd", [["run"], ["sweep", "--runs", "2", "--workers", "2"]])
def test_full_disk_is_one_line_and_leaves_nothing(tmp_path, tmpfs, cmd):
    small = tmpfs("size=64k")
    q = _testbed(tmp_path, cmd[0], "bandwidth", "--duration", "4", *cmd[1:], "--out", f"{small.name}/out")
    assert q.returncode == 2, q.stderr
    (line,) = q.stderr.splitlines()
    assert line.startswith(f"testbed: error: {small.name}/out") and "No space left on device" in line, line
    assert os.listdir(small) == []


def test_read_only_disk_is_one_line_and_leaves_nothing(tmp_path, tmpfs):
    ro = tmpfs("size=64k,ro")
    q = _testbed(tmp_path, "run", "bandwidth", "--duration", "0.5", "--out", f"{ro.name}/r")
    assert q.returncode == 2
    (line,) = q.stderr.splitlines()
    assert line.startswith(f"testbed: error: {ro.name}/r: Read-only file system"), line
    assert os.listdir(ro) == []


@pytest.mark.parametrize("out", ["/proc/testbed-run", "/proc/self/run"])
def test_a_path_under_proc_is_one_line(tmp_path, capsys, monkeypatch, out):
    monkeypatch.chdir(tmp_path)
    assert main(["run", "bandwidth", "--duration", "0.5", "--out", out]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"testbed: error: {out}: ")


def test_closed_pipe_ends_quietly(tmp_path):
    p = subprocess.Popen([sys.executable, "-m", "testbed", "list"], cwd=tmp_path, env=_env(), stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE)
    p.stdout.close()  # the reader is gone before the first line (`testbed list | head -0`)
    err = p.stderr.read()
    assert p.wait(timeout=60) == 128 + signal.SIGPIPE
    assert err == b""
    q = subprocess.run(f"{sys.executable} -m testbed list | head -1", shell=True, cwd=tmp_path, env=_env(), capture_output=True)
    assert len(q.stdout.splitlines()) == 1 and q.stderr == b""


def test_runs_done_counts_finished_run_directories_and_kept_results(tmp_path):
    from testbed.outdir import write_marker
    from testbed.reproduce.runs import load_result, runs_done, save_result

    finished = tmp_path / "runs" / "a" / "run-000"
    finished.mkdir(parents=True)
    write_marker(finished, "run")
    (finished / "metrics.json").write_text("{}\n")
    (tmp_path / "runs" / "a" / "run-001").mkdir()  # no marker, no metrics: not finished
    result = {"glint": {"t": np.arange(3.0), "metrics": {"ekf": {"rmse_position_m": 0.25}}}}
    save_result(tmp_path / "runs-kept", 4, result)
    assert runs_done(tmp_path) == 2
    back = load_result(tmp_path / "runs-kept", 4)
    assert back["glint"]["metrics"] == result["glint"]["metrics"] and np.array_equal(back["glint"]["t"], result["glint"]["t"])
    assert load_result(tmp_path / "runs-kept", 3) is None
    assert _debris(tmp_path) == []
