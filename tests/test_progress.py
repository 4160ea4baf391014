"""Progress and a last line: sweep and reproduce draw a bar over their runs (with the time left) on
stderr only when it is a terminal and not --quiet; every long command ends with one line on
stdout naming what it wrote and where."""
from __future__ import annotations

import fcntl
import json
import os
import pty
import select
import struct
import subprocess
import sys
import termios
from pathlib import Path

import pytest

from testbed import progress
from testbed.cli import main
from testbed.reproduce.runs import run_plots, sweep_runs
from testbed.config.scenario import load

ROOT = Path(__file__).resolve().parent.parent
SWEEP = ["sweep", "bandwidth", "--runs", "2", "--duration", "0.5", "--workers", "1", "--no-plots"]


def _sweep(out: Path, *extra: str) -> tuple[str, str]:
    """(stdout, stderr) of `testbed sweep` in a subprocess, its stderr a pseudo-terminal."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    cmd = [sys.executable, "-m", "testbed", *SWEEP, "--out", str(out), *extra]
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 120, 0, 0))  # a terminal of 120 columns
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=slave, env=env, text=True)
    os.close(slave)
    err = b""
    while True:  # read the terminal until the child closes it
        ready, _, _ = select.select([master], [], [], 300)
        try:
            chunk = os.read(master, 4096) if ready else b""
        except OSError:  # EIO: the child is gone
            chunk = b""
        if not chunk:
            break
        err += chunk
    os.close(master)
    out_text = p.stdout.read()
    assert p.wait(timeout=60) == 0, err
    return out_text, err.decode(errors="replace")


def test_sweep_bar_on_a_terminal_only_and_not_with_quiet(tmp_path, capsys):
    out, err = _sweep(tmp_path / "a")
    assert "sweep bandwidth" in err and "2/2" in err and ("run/s" in err or "s/run" in err)
    assert "<" in err  # tqdm's elapsed<remaining: the time left
    assert out.splitlines()[-1].startswith(f"2 runs -> {tmp_path / 'a'}/summary.csv")
    out, err = _sweep(tmp_path / "b", "--quiet")
    assert "sweep bandwidth" not in err and "2/2" not in err
    # stderr not a terminal (captured here, as a pipe is): in this process, which saves an interpreter start
    assert not sys.stderr.isatty()
    capsys.readouterr()
    assert main([*SWEEP, "--out", str(tmp_path / "c")]) == 0
    out, err = capsys.readouterr()
    assert "sweep bandwidth" not in err and "2/2" not in err
    assert out.splitlines()[-1].startswith(f"2 runs -> {tmp_path / 'c'}/summary.csv")


def test_a_reproduction_s_runs_show_the_bar_the_command_asked_for(tmp_path, capsys):
    sc = load("bandwidth", duration=0.5)
    with progress.shown(True), run_plots(False):
        sweep_runs(sc, 2, tmp_path / "on", workers=1)
    assert "2/2" in capsys.readouterr().err
    with run_plots(False):
        sweep_runs(sc, 2, tmp_path / "off", workers=1)  # outside a command that shows progress
    assert capsys.readouterr().err == ""


def test_wanted_means_a_terminal_and_not_quiet(monkeypatch):
    class Tty:
        def __init__(self, tty: bool):
            self.tty = tty

        def isatty(self) -> bool:
            return self.tty

    monkeypatch.setattr(sys, "stderr", Tty(True))
    assert progress.wanted(quiet=False) and not progress.wanted(quiet=True)
    monkeypatch.setattr(sys, "stderr", Tty(False))
    assert not progress.wanted(quiet=False)


@pytest.mark.parametrize("quiet", [False, True])
def test_reproduce_shows_progress_unless_quiet_and_ends_with_its_line(tmp_path, capsys, monkeypatch, quiet):
    import testbed.reproduce as reproduce_mod

    seen = {}

    def fake(paper, out, **kw):  # the command's wiring only: a reproduction is minutes long
        seen["progress"] = progress.enabled()
        Path(out).mkdir()
        (Path(out) / "claims.json").write_text(json.dumps({"claims": [{"holds": True}, {"holds": False}]}))

    monkeypatch.setattr(reproduce_mod, "reproduce", fake)
    monkeypatch.setattr(progress.sys.stderr, "isatty", lambda: True)
    out = tmp_path / "r"
    assert main(["reproduce", "coop", "--out", str(out), *(["--quiet"] if quiet else [])]) == 0
    assert seen["progress"] is not quiet
    assert capsys.readouterr().out.splitlines()[-1] == f"reproduce coop: 1 of 2 claims hold -> {out}/report.html"


def test_run_export_render_end_with_what_they_wrote(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["run", "bandwidth", "--duration", "0.5", "--out", str(run), "--no-plots"]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == f"run directory -> {run}"
    assert main(["export", str(run), "--out", str(tmp_path / "data")]) == 0
    assert capsys.readouterr().out.splitlines()[-1].startswith(f"{run} -> {tmp_path / 'data'}: ")
    assert main(["render", str(run), "--max-seconds", "0.1", "--width", "64", "--height", "48", "--shadow-size", "0"]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == f"video of {run} -> {run / 'video.mp4'}"


def test_bench_and_demo_end_with_what_they_wrote(tmp_path, capsys, monkeypatch):
    import testbed.bench.run as bench_mod
    import testbed.demo as demo_mod

    monkeypatch.setattr(bench_mod, "bench", lambda what, path, vehicles=None: {})  # the wiring: benches are minutes long
    assert main(["bench", "physics", "--json", str(tmp_path / "b.json")]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == f"bench physics -> {tmp_path / 'b.json'}"
    assert main(["bench", "physics"]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == "bench physics: figures above (--json FILE saves them)"
    monkeypatch.setattr(demo_mod, "_demo", lambda out: (out / "summary.md").write_text("# Demo results\n"))
    assert main(["demo", "--out", str(tmp_path / "demo")]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == f"demo results in {tmp_path / 'demo'}/summary.md"
