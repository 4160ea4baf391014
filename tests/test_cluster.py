"""Ray backend of sweeps and reproductions: the same bytes as the local process pool, clean stops,
--resume. A local Ray instance with 2 CPUs (started here, or by the command under test)."""
import json
import signal
import time

import pytest
import ray

from testbed.config import scenario
from testbed import sweep as sweep_mod
from testbed.cluster import TaskLost
from testbed.errors import RunError, UsageError
from testbed.sweep import sweep
from testbed.workers import backend
from testbed.cli import main
from tests.test_faults import _debris, _start, _tmp_dirs, _wait_for

FILES = ["summary.json", "summary.csv", "sweep.toml", *(f"run-{i:03d}/{f}" for i in range(3)
                                                        for f in ("metrics.json", "log.npz"))]


@pytest.fixture
def local_ray():
    """A local Ray instance for one test, stopped after it: idle, it would still cost CPU while the
    interrupted sweep below starts its own."""
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


@pytest.fixture(scope="module")
def local_pool(tmp_path_factory):
    """The reference both Ray tests compare with: bandwidth, seed 3, 1 s, 3 runs swept by the local
    backend, computed once, without figures as every sweep here: (its directory, its summary). One
    worker: the runs one after the other in this process, no pool's interpreters to start; the
    local pool of 2 workers gives the same bytes (tests/test_sweep.py, tests/test_faults.py)."""
    out = tmp_path_factory.mktemp("local") / "sw"
    summary = sweep(scenario.load("bandwidth", duration=1.0, seed=3), 3, out, workers=1, progress=False, plots=False)
    return out, summary


def test_ray_sweep_is_byte_identical_to_the_local_pool(tmp_path, local_ray, local_pool):
    sc = scenario.load("bandwidth", duration=1.0, seed=3)
    by_ray = sweep(sc, 3, tmp_path / "ray", backend="ray", progress=False, plots=False)
    local_dir, local = local_pool
    assert by_ray == local and local["tracking_rmse_m.0"]["n"] == 3
    for f in FILES:
        assert (tmp_path / "ray" / f).read_bytes() == (local_dir / f).read_bytes(), f
    made = json.loads((tmp_path / "ray" / "run-000" / "provenance.json").read_text())
    assert made["output"] == "run" and made["command"]["function"] == "testbed.sweep.sweep"  # carried into the task
    assert _debris(tmp_path) == []


def test_backend_choices_are_checked():
    with pytest.raises(UsageError, match="--backend 'slurm'"), backend("slurm"):
        pass
    with pytest.raises(UsageError, match="--address 'auto' needs --backend ray"), backend("local", "auto"):
        pass


def test_a_task_lost_for_good_keeps_the_finished_runs(tmp_path, monkeypatch):
    def first_then_lost(fn, jobs, workers):
        fn(jobs[0])
        yield 0, None
        raise TaskLost("Ray lost job 1: NodeDiedError")

    monkeypatch.setattr(sweep_mod, "run_parallel", first_then_lost)
    sc = scenario.load("bandwidth", duration=0.5, seed=3)
    with pytest.raises(RunError, match=r"Ray lost job 1: NodeDiedError; 1 of 2 runs kept in .*--resume"):
        sweep(sc, 2, tmp_path / "sw", progress=False, plots=False)
    summary = json.loads((tmp_path / "sw" / "summary.json").read_text())
    assert summary["incomplete"] is True and summary["runs_done"] == 1 and summary["seeds"] == [3]
    assert _debris(tmp_path) == []


@pytest.mark.slow  # starts Ray twice (the command line, then this process), ~1.5 min on a loaded machine
def test_interrupted_ray_sweep_keeps_finished_runs_and_resumes_byte_identical(tmp_path, local_pool, monkeypatch):
    args = ["sweep", "bandwidth", "--runs", "3", "--duration", "1.0", "--seed", "3", "--backend", "ray", "--no-plots"]
    # one task at a time: with two, the second finishes with the first, and the signal that follows
    # the first would meet the second's completion (a race inside Ray, not the testbed's to test)
    p = _start(tmp_path, *args, "--workers", "1", "--out", "sw")
    _wait_for(lambda: any((d / "metrics.json").is_file() for t in _tmp_dirs(tmp_path, "sw") for d in t.glob("run-*")),
              "a finished run", timeout=240.0)
    p.send_signal(signal.SIGINT)
    t0 = time.monotonic()
    _, err = p.communicate(timeout=60)
    assert time.monotonic() - t0 < 30.0
    assert p.returncode == 130, err
    done = sorted(d.name for d in (tmp_path / "sw").glob("run-*"))
    assert 1 <= len(done) <= 3
    summary = json.loads((tmp_path / "sw" / "summary.json").read_text())
    if len(done) < 3:
        assert summary["incomplete"] is True and summary["runs_done"] == len(done)
    assert _debris(tmp_path) == []
    # the command that follows the interruption, in this process (it starts its own Ray here, as
    # the command line does; no local_ray is left running): saves an interpreter start
    monkeypatch.chdir(tmp_path)
    assert main([*args, "--out", "sw", "--resume"]) == 0
    whole = local_pool[0]  # the same sweep uninterrupted (the local pool: the Ray sweep's bytes, test above)
    for f in FILES:
        assert (tmp_path / "sw" / f).read_bytes() == (whole / f).read_bytes(), f
    assert _debris(tmp_path) == []
