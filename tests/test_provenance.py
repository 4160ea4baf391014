"""Provenance: provenance.json in every kind of output, its fields, strict
JSON, load_run's `provenance`, the git commit and dirty flag, the command carried into workers."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from datetime import datetime
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest

import testbed
from testbed import provenance
from testbed.cli import main
from testbed.outdir import Output

ROOT = Path(__file__).resolve().parent.parent
FIELDS = {"testbed", "command", "output", "python", "packages", "blas", "cpu", "platform", "environment", "time"}


def _strict(path: Path) -> dict:
    """The JSON document at path; NaN or Infinity in it fails the test."""
    def refuse(token: str):
        raise AssertionError(f"{path}: non-strict JSON token {token}")
    return json.loads(path.read_text(), parse_constant=refuse)


def _check(doc: dict, output: str) -> None:
    """The fields of a record made in this test process (its packages, CPU, environment)."""
    assert set(doc) == FIELDS and doc["output"] == output
    assert doc["testbed"]["version"] == testbed.__version__
    assert doc["packages"]["numpy"] == np.__version__ and doc["packages"]["uav-swarm-testbed"] == testbed.__version__
    assert doc["python"]["version"] == ".".join(map(str, sys.version_info[:3]))
    assert any(lib["user_api"] == "blas" and lib["version"] for lib in doc["blas"])
    for lib in doc["blas"]:
        if lib["internal_api"] == "openblas":  # the kernel OpenBLAS chose for this CPU
            assert isinstance(lib["architecture"], str) and lib["architecture"]
    assert doc["cpu"]["cores"] == os.cpu_count() and doc["cpu"]["model"]
    assert doc["environment"] == {k: os.environ.get(k) for k in provenance.ENVIRONMENT}
    t = doc["time"]
    span = datetime.fromisoformat(t["finished_utc"]) - datetime.fromisoformat(t["started_utc"])
    assert abs(span.total_seconds() - t["wall_s"]) < 0.05  # the UTC stamps and the monotonic span agree
    assert t["wall_s"] >= 0 and t["cpu_s"] >= 0 and t["children_cpu_s"] >= 0


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("prov") / "run"
    testbed.run(testbed.load_scenario("bandwidth", duration=1.0), out, plots=False)
    return out


def test_a_run_directory_records_its_provenance_and_load_run_exposes_it(run_dir):
    doc = _strict(run_dir / "provenance.json")
    _check(doc, "run")
    assert doc["command"]["interface"] == "python API" and doc["command"]["function"] == "testbed.api.run"
    assert doc["time"]["wall_s"] > 0 and doc["time"]["cpu_s"] > 0  # a second of flight was simulated
    assert "provenance" not in json.loads((run_dir / "metrics.json").read_text())  # metrics stay comparable
    r = testbed.load_run(run_dir)
    assert r.provenance == doc and r.files["provenance.json"] == run_dir / "provenance.json"


def test_a_run_without_provenance_loads_with_none(run_dir, tmp_path):
    old = tmp_path / "old"
    shutil.copytree(run_dir, old)
    (old / "provenance.json").unlink()
    r = testbed.load_run(old)
    assert r.provenance is None and "provenance.json" not in r.files and r.metrics


def test_an_exported_dataset_and_its_replay_record_their_provenance(run_dir, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["export", str(run_dir), "--out", "ds"]) == 0
    doc = _strict(tmp_path / "ds" / "provenance.json")
    _check(doc, "dataset")
    assert doc["command"] == {"interface": "command line", "argv": ["testbed", "export", str(run_dir), "--out", "ds"],
                              "line": f"testbed export {run_dir} --out ds"}
    spec = tmp_path / "ex" / "spec.toml"
    shutil.copytree(ROOT / "examples/replay", spec.parent)
    text = spec.read_text()
    start, end = text.index("[[estimators]]"), text.index("[window]")  # its five [[estimators]] tables
    spec.write_text(text[:start] + '[[estimators]]\nentry = "coop.gnss_only"\n\n' + text[end:])  # one fast estimator
    assert main(["replay", str(spec), "--out", "rp"]) == 0, capsys.readouterr().err
    doc = _strict(tmp_path / "rp" / "provenance.json")
    _check(doc, "replay")
    assert doc["command"]["argv"] == ["testbed", "replay", str(spec), "--out", "rp"]


def test_a_sweep_and_its_runs_in_worker_processes_record_the_command(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = ["sweep", "bandwidth", "--duration", "1", "--runs", "2", "--workers", "2", "--out", "sw", "--no-plots"]
    assert main(argv) == 0
    top = _strict(tmp_path / "sw" / "provenance.json")
    _check(top, "sweep")
    assert top["time"]["children_cpu_s"] > 0  # the worker pool's CPU time, waited for before the record
    for run in ("run-000", "run-001"):
        doc = _strict(tmp_path / "sw" / run / "provenance.json")
        assert doc["output"] == "run" and doc["command"]["argv"] == ["testbed", *argv]  # carried into the worker
        assert doc["time"]["cpu_s"] > 0
    assert "provenance" not in json.loads((tmp_path / "sw" / "summary.json").read_text())


@pytest.mark.parametrize("kind", ["reproduce-coop", "demo"])
def test_every_output_directory_gets_provenance_on_commit_and_none_without(tmp_path, kind):
    with Output(tmp_path / "o", kind=kind) as o:
        (o.path / "x.txt").write_text("x")
        o.commit()
    doc = _strict(tmp_path / "o" / "provenance.json")
    assert doc["output"] == kind  # written from outside any testbed function:
    assert doc["command"] == {"interface": "python API", "function": None, "argv": sys.argv}
    with pytest.raises(RuntimeError), Output(tmp_path / "p", kind=kind) as o:
        raise RuntimeError("a failed write")
    assert not (tmp_path / "p").exists() and not list(tmp_path.glob(".p.*"))


def test_a_resumed_output_records_the_command_that_finished_it(tmp_path):
    with Output(tmp_path / "o", kind="sweep") as o:
        o.commit()
    first = _strict(tmp_path / "o" / "provenance.json")
    with provenance.command_line(["sweep", "--resume"]), Output(tmp_path / "o", kind="sweep", resume=True) as o:
        assert o.resume
        o.commit()
    again = _strict(tmp_path / "o" / "provenance.json")
    assert first["command"]["interface"] == "python API" and again["command"]["argv"] == ["testbed", "sweep", "--resume"]


def test_bench_json_holds_the_provenance_beside_the_figures(tmp_path, monkeypatch, capsys):
    """The figures do not matter here (a stand-in family); the record does."""
    monkeypatch.setattr("testbed.bench.run.bench_physics", lambda sizes: {"rows": [{"vehicles": 1, "flown_rtf": 2.0}],
                                                                           "growth_exponent": {}})
    out = tmp_path / "bench.json"
    assert main(["bench", "physics", "--vehicles", "1", "--json", str(out)]) == 0
    doc = _strict(out)
    assert doc["physics"] == [{"vehicles": 1, "flown_rtf": 2.0}] and set(doc["machine"]) == {"load_average_1_5_15min"}
    _check(doc["provenance"], "bench-physics")
    assert doc["provenance"]["command"]["argv"] == ["testbed", "bench", "physics", "--vehicles", "1", "--json", str(out)]


def _git(repo: Path, *args: str) -> None:
    subprocess.run(["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t", *args], check=True,
                   capture_output=True)


@pytest.fixture
def source(tmp_path, monkeypatch):
    """provenance.SOURCE moved to an empty directory, the per-process git answer forgotten."""
    monkeypatch.setattr(provenance, "SOURCE", tmp_path / "src")
    (tmp_path / "src").mkdir()
    provenance.git.cache_clear()
    yield tmp_path / "src"
    provenance.git.cache_clear()


def test_git_commit_and_dirty_flag_of_a_checkout(source):
    _git(source, "init", "-q")
    (source / "a.py").write_text("x = 1\n")
    _git(source, "add", "a.py")
    _git(source, "commit", "-qm", "one")
    head = subprocess.run(["git", "-C", str(source), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    assert provenance.git() == ({"commit": head, "dirty": False}, None)
    (source / "notes.txt").write_text("untracked\n")  # not counted
    provenance.git.cache_clear()
    assert provenance.git() == ({"commit": head, "dirty": False}, None)
    (source / "a.py").write_text("x = 2\n")
    provenance.git.cache_clear()
    assert provenance.git() == ({"commit": head, "dirty": True}, None)


def test_git_is_null_with_a_reason_outside_a_checkout_or_without_git(source, monkeypatch):
    inner = source / "site-packages"  # inside someone's repository, but not its root: not our checkout
    inner.mkdir()
    _git(source, "init", "-q")
    monkeypatch.setattr(provenance, "SOURCE", inner)
    commit, note = provenance.git()
    assert commit is None and note.startswith("not a git checkout") and str(inner) in note
    provenance.git.cache_clear()
    monkeypatch.setenv("PATH", str(source / "no-bin"))
    assert provenance.git() == (None, "git is not installed")


@pytest.fixture
def fresh_packages():
    provenance.packages.cache_clear()
    yield
    provenance.packages.cache_clear()


def test_packages_are_the_declared_requirements_or_every_distribution(fresh_packages, monkeypatch):
    declared = ["numpy>=1.26", "no-such-package[extra]>=1; extra == 'test'", "pytest[testing]>=8 ; extra == 'test'"]
    monkeypatch.setattr(metadata, "requires", lambda name: declared)
    assert provenance.packages() == {"no-such-package": None, "numpy": np.__version__, "pytest": pytest.__version__,
                                     provenance.DISTRIBUTION: metadata.version(provenance.DISTRIBUTION)}
    provenance.packages.cache_clear()

    def not_installed(name):  # run from a checkout, the testbed not installed
        raise metadata.PackageNotFoundError(name)
    monkeypatch.setattr(metadata, "requires", not_installed)
    every = provenance.packages()
    assert every["numpy"] == np.__version__ and None not in every.values() and len(every) > len(declared)
