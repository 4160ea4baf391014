"""Architecture: the layer table of docs/architecture.md (every module of testbed/ has a layer and
imports only from its own layer and the layers its layer may use), no import cycles among the
project's modules, no sys.path edits, estimators/ a leaf that never imports mujoco or testbed, a
light scenario schema, and `import testbed` without side effects."""
from __future__ import annotations

import ast
import json
import multiprocessing as mp
import os
import subprocess
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from testbed.environment import DEFAULTS, apply_defaults

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("testbed", "estimators")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _project_modules() -> dict[str, Path]:
    return {_module_name(p): p for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))}


def _imports(path: Path, name: str, modules: dict[str, Path]) -> set[str]:
    """Project modules imported anywhere in the file (module level, in functions, under
    TYPE_CHECKING alike). `from a.b import c` counts as a.b.c when that is a module, else a.b."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in modules:  # `import a.b.c` of a non-module attribute: nearest module
                t = t.rpartition(".")[0]
            if t and t != name:
                out.add(t)
    return out


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan), plus self-loops."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1 or v in graph[v]:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def _import_graph() -> dict[str, set[str]]:
    modules = _project_modules()
    return {name: _imports(path, name, modules) for name, path in modules.items()}


# The layer table of docs/architecture.md, bottom to top: (layer, its modules, the layers it may
# import besides its own). A module belongs to the entry that is the longest prefix of its dotted
# name (`testbed.plugins` holds every plugins module not named more precisely). estimators/ (the
# library) is below them all and imports none of them (test_estimators_never_import_mujoco_or_testbed).
LAYERS: list[tuple[str, tuple[str, ...], frozenset[str]]] = []


def _layer(name: str, modules: str, uses: str = "") -> None:
    LAYERS.append((name, tuple(f"testbed.{m}" if m else "testbed" for m in modules.split()) if modules != "." else ("testbed",),
                   frozenset(u.strip() for u in uses.split(",") if u.strip())))


_layer("foundations", "errors rng log environment outdir provenance interrupt progress worker_process")
_layer("configuration", "config scenarios trajectories reference "
       "sensors.config sensors.presets", "foundations")
_layer("protocol", "plugins.api stream", "foundations, configuration")
_layer("simulation", "sim sensors",
       "foundations, configuration, protocol")
_layer("estimation", "plugins synthetic replay.graph", "foundations, configuration, protocol")
_layer("scoring and outputs", "scoring outputs reproduce.document plugins.truth "
       "plugins.score plugins.hooks plugins.coop_scores plugins.graph_check plugins.phase_scores plugins.relnav_scores "
       "plugins.fusion_bound", "foundations, configuration, protocol, simulation, estimation")
_layer("workflows", "runner sweep demo workers cluster viewer bench reproduce replay plugins.run plugins.online plugins.priors "
       "plugins.channel plugins.context", "foundations, configuration, protocol, simulation, estimation, scoring and outputs")
_layer("python api", "api truth replay.export replay.bag_export",
       "foundations, configuration, protocol, simulation, estimation, scoring and outputs, workflows")
_layer("command line", "cli __main__", "foundations, configuration, protocol, simulation, estimation, "
       "scoring and outputs, workflows, python api")
LAYERS[0] = (LAYERS[0][0], LAYERS[0][1] + ("testbed",), LAYERS[0][2])  # the package itself: its version only

# Upward imports not fixed yet, each with why; the test fails when one of them is gone (remove it
# here) as when a new one appears. Every entry is a debt against the layer table of docs/architecture.md.
KNOWN_UPWARD: dict[tuple[str, str], str] = {}


def layer_of(module: str) -> str | None:
    """The layer of a dotted module name of testbed/ (None: it has none)."""
    best, found = -1, None
    for name, modules, _ in LAYERS:
        for m in modules:
            if (module == m or module.startswith(m + ".")) and len(m) > best:
                best, found = len(m), name
    return found


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    """'a -> b (layer A may not import layer B)' for every import of graph that the table forbids."""
    uses = {name: u | {name} for name, _, u in LAYERS}
    out = []
    for a in sorted(m for m in graph if m.startswith("testbed")):
        for b in sorted(x for x in graph[a] if x.startswith("testbed")):
            la, lb = layer_of(a), layer_of(b)
            if lb not in uses[la]:
                out.append(f"{a} -> {b} ({la} may not import {lb})")
    return out


def test_layer_checker_finds_a_planted_upward_import():
    graph = {"testbed.plugins.lsq": {"testbed.sim.world", "testbed.config", "estimators.core"},
             "testbed.config.scenario": {"testbed.plugins.loading"}, "testbed.outputs.render": {"testbed.workers"},
             "testbed.runner": {"testbed.sim.world", "testbed.outputs.plots"}}
    assert upward_imports(graph) == [
        "testbed.config.scenario -> testbed.plugins.loading (configuration may not import estimation)",
        "testbed.outputs.render -> testbed.workers (scoring and outputs may not import workflows)",
        "testbed.plugins.lsq -> testbed.sim.world (estimation may not import simulation)"]


def test_every_module_has_a_layer():
    missing = [m for m in _project_modules() if m.startswith("testbed") and layer_of(m) is None]
    assert missing == []


def test_no_upward_import():
    """The documented layers hold: the estimator runtime never imports the simulator, scoring or
    plots; configuration never imports a runtime; outputs never import workflows (docs/architecture.md)."""
    found = upward_imports(_import_graph())
    known = {f"{a} -> {b}" for a, b in KNOWN_UPWARD}
    new = [f for f in found if f.split(" (")[0] not in known]
    gone = sorted(known - {f.split(" (")[0] for f in found})
    assert new == [] and gone == [], f"upward imports: {new}; fixed, remove from KNOWN_UPWARD: {gone}"


def test_cycle_finder_finds_a_planted_cycle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": {"e"}, "f": set()}
    assert _cycles(graph) == [["a", "b", "c"], ["e"]]


def test_no_import_cycles_in_the_project():
    graph = _import_graph()
    assert len(graph) > 40 and "testbed.config.scenario" in graph["testbed.reference"]  # the finder sees edges
    assert _cycles(graph) == []


def test_estimators_never_import_mujoco_or_testbed():
    for path in sorted((ROOT / "estimators").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            bad = [n for n in names if n.split(".")[0] in ("mujoco", "testbed")]
            assert not bad, f"{path.relative_to(ROOT)}:{node.lineno} imports {bad}"


def _sys_path_edits(source: str) -> list[int]:
    """Lines that use sys.path at all (insert, append, assignment...): the project needs none."""
    lines = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Attribute) and node.attr == "path" and isinstance(node.value, ast.Name) and node.value.id == "sys":
            lines.append(node.lineno)
    return lines


def test_no_sys_path_edits_in_the_repository():
    assert _sys_path_edits("import sys\nsys.path.insert(0, 'x')\n") == [2]  # the check can fail
    files = [p for p in ROOT.rglob("*.py") if not any(part.startswith(".") or part in ("build", "runs") for part in p.relative_to(ROOT).parts)]
    assert len(files) > 40
    offenders = [f"{p.relative_to(ROOT)}:{ln}" for p in files for ln in _sys_path_edits(p.read_text())]
    assert offenders == []


def _fresh(code: str, env: dict | None = None) -> dict:
    """Run code in a fresh interpreter from the repository root; it prints one JSON object."""
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, env=env, timeout=120)
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout)


def test_scenario_schema_loads_without_compute_modules_scipy_or_mujoco():
    loaded = _fresh(
        "import json, sys\n"
        "import testbed.config.scenario as s\n"
        "s.load('coop-fg'); s.load('phase-cross-h000')\n"
        "print(json.dumps(sorted(sys.modules)))\n"
    )
    heavy = [m for m in loaded if m.split(".")[0] in ("scipy", "mujoco", "cv2", "matplotlib", "gtsam", "filterpy")]
    compute = [m for m in loaded if m.startswith(("testbed.plugins.", "testbed.sensors.", "estimators"))
               and m not in ("testbed.config.pipelines", "testbed.sensors.config", "testbed.sensors.presets",
                             "estimators", "estimators.visnav_paper",  # the paper's constants: plain floats
                             "estimators.sensor_models")]  # the assumed sensor models: numpy only
    assert "testbed.config.pipelines" in loaded and heavy == [] and compute == []


def test_import_testbed_leaves_the_environment_alone():
    env = {k: v for k, v in os.environ.items() if k not in DEFAULTS}
    code = ("import json, os\nbefore = dict(os.environ)\nimport testbed, testbed.config.scenario, testbed.outputs.plots\n"
            "print(json.dumps([before == dict(os.environ), 'matplotlib.pyplot' in __import__('sys').modules]))\n")
    assert _fresh(code, env) == [True, False]


def test_cli_sets_the_environment_before_numpy_loads():
    env = {k: v for k, v in os.environ.items() if k not in DEFAULTS}
    code = ("import json, os, sys, contextlib, io\nfrom testbed.cli import main\nnumpy_before = 'numpy' in sys.modules\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n    main(['list'])\n"
            "print(json.dumps([numpy_before, {k: os.environ.get(k) for k in %r}]))\n" % list(DEFAULTS))
    numpy_before, seen = _fresh(code, env)
    assert numpy_before is False and seen == DEFAULTS


def _worker_env() -> dict:
    return {k: os.environ.get(k) for k in DEFAULTS}


def test_sweep_workers_get_single_threaded_blas(monkeypatch):
    """The pool set-up of testbed.sweep: spawned workers run apply_defaults before any task (and
    so before the task's module imports numpy), even when the parent never set the variables."""
    for k in DEFAULTS:
        monkeypatch.delenv(k, raising=False)
    with ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("spawn"), initializer=apply_defaults) as pool:
        assert pool.submit(_worker_env).result() == DEFAULTS
    assert all(k not in os.environ for k in DEFAULTS)  # the parent is left alone


def test_plots_never_choose_a_backend_or_use_pyplot():
    tree = ast.parse((ROOT / "testbed/outputs/plots.py").read_text())
    calls = [ast.unparse(n.func) for n in ast.walk(tree) if isinstance(n, ast.Call)]
    imports = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names] + \
        [n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    assert "matplotlib.use" not in calls and not any("pyplot" in (m or "") for m in imports)
