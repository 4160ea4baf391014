"""`testbed reproduce denied`: cooperative flight through GNSS-denied streets (docs/denied.md).

Scenario `coop-denied` (18 UAVs down an urban street and under a covered passage; GNSS by sky
visibility, UWB among vehicles and to anchors, network on; docs/denied.md) flown over `runs`
seeds in eight variants, each its own sweep (OUT/runs/<variant>/run-XXX, run i: seed + i,
testbed.reproduce.runs). The estimators are testbed.plugins.builtin_coop_ins's (IMU error-state
EKFs per vehicle updated by GNSS, UWB ranges to anchors and UWB ranges between vehicles) and
testbed.plugins.builtin_window_ins's (seed 001's graph over a sliding window, the IMU filters
updated by it).
- truth:       the controller flies on the MuJoCo state; the centralized `coop.ins` is run and
               scored beside it: its estimation error without feedback;
- gnss_ekf:    flies on `coop.ins` with no UWB ([sensors.uwb] removed in this variant): the same
               IMU + GNSS filter per vehicle, GNSS only;
- coop:        flies on `coop.ins`, centralized (one joint covariance over the swarm, every
               measurement reaches it);
- coop_distributed: flies on `coop.ins_distributed` (a filter per vehicle; neighbours'
               broadcasts over the scenario's [network]);
- coop_lossy:  the distributed estimator over a lossy network (LOSSY: loss and latency raised);
- coop_onboard: as coop_distributed, the attitude loop on the filter's attitude too ([control]
               attitude = "estimate"): nothing in the loop reads the truth. The other variants
               fly the attitude loop on the MuJoCo attitude (docs/control.md).
- window:      flies on `coop.window_ins`: seed 001's graph over a sliding window of epochs,
               centralized, the per-vehicle IMU filters updated by its new information;
- window_distributed: flies on `coop.window_distributed_ins`: the window per vehicle, seed 001's
               message iteration over the scenario's [network].
The three variants on coop.ins_distributed start with the initialization phase ([control]
release_sigmas, the scenario file's 1 sigma): each vehicle flies on its reference until its estimate has
converged (docs/control.md); the others fly on their estimator's first output.
Metrics per run, from the log (truth only for scoring): tracking error |p_true - p_ref| (RMS and
max over vehicles and time); the feedback estimator's position RMSE (metrics.json); and from the
run's safety (metrics.json `flight`, testbed.scoring.safety, as in every flown run): minimum separation
between vehicles, contact events by kind (vehicle, obstacle, floor), crashed vehicles, seconds
without a GNSS fix per vehicle.

Claims (criteria fixed here, before the runs): no contact (with a vehicle, an obstacle or the
floor: a vehicle fallen to the floor is no clean flight) when flying on the cooperative estimate,
centralized, distributed, distributed without truth, and on the two window cascades (one claim each; the window variants' claims were added before their first run on these seeds);
cooperation's estimation error below GNSS-only's, the same five (one-sided Wilcoxon
signed-rank over paired runs at alpha = 0.05 from 2 runs on; 1 run: point values, said so); these
are about a street that denies GNSS, so they are "not decidable" (testbed.outputs.report.Claim) unless a
vehicle of the variant's or the GNSS-only runs spent some time without a fix (a short run that
never reaches the covered passage).

Plugin estimators (`--estimator`): each is added to every variant's estimators and runs on that
variant's flown log after the flight, offline: it does not fly (the controller flies on the
variant's own estimator; the flights, and so the built-ins' numbers and claims, are the same with
or without it). Every table and figure that shows an estimator's position RMSE shows it per
variant beside the variant's own, with the paired tests of testbed.reproduce.plugins against each
variant's estimator over the same seeds (table_plugins.csv, table_plugins_paired.csv: the factor
mean RMSE of the variant's estimator / the plugin's, and the two-sided Wilcoxon signed-rank test).

Shape (as every reproduction): `compute` (runs -> `DeniedResults`), `decide` (numbers ->
claims), `write` (files through testbed.outputs.report); `reproduce` chains them.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from testbed.config import to_dict
from testbed.errors import UsageError
from testbed.log import load_log
from testbed.outputs.plots import grouped_bars
from testbed.config.estimators import EstimatorSpec
from testbed.outputs.report import Claim, fmt, markdown_table, write_claims, write_csv, write_markdown
from testbed.reproduce import plugins as plugin_rows
from testbed.reproduce.runs import load_metrics, seeds, sweep_runs
from testbed.config.scenario import Scenario, load
from testbed.scoring.stats import wilcoxon_paired

VARIANTS = ("truth", "gnss_ekf", "coop", "coop_distributed", "coop_lossy", "coop_onboard", "window", "window_distributed")
TITLES = {"truth": "control on truth", "gnss_ekf": "GNSS-only EKF", "coop": "cooperative, centralized",
          "coop_distributed": "cooperative, distributed", "coop_lossy": "cooperative, distributed, lossy network",
          "coop_onboard": "cooperative, distributed, attitude from the filter (no truth in the loop)",
          "window": "seed 001 window cascade, centralized", "window_distributed": "seed 001 window cascade, distributed"}
COOP, EKF = "coop", "ekf"  # estimator names ([[estimators]] name) of the cooperative and GNSS-only estimators
COOPERATIVE = ("coop", "coop_distributed", "coop_onboard", "window", "window_distributed")  # the variants the claims are about
LOSSY = {"loss_prob": 0.3, "latency": 0.006, "jitter": 0.003}  # the lossy variant's [network] changes
ALPHA = 0.05
# the cooperative estimator of each variant (testbed.plugins.builtin_coop_ins, builtin_window_ins)
COOP_ENTRY = {"truth": "coop.ins", "coop": "coop.ins", "coop_distributed": "coop.ins_distributed",
              "coop_lossy": "coop.ins_distributed", "coop_onboard": "coop.ins_distributed",
              "window": "coop.window_ins", "window_distributed": "coop.window_distributed_ins"}
METRICS = ("tracking_rms_m", "tracking_max_m", "estimation_rmse_m", "min_separation_m", "contacts_vehicle",
           "contacts_obstacle", "contacts_floor", "crashed", "no_fix_mean_s", "no_fix_max_s")


def variant(base: Scenario, name: str) -> Scenario:
    """The scenario of variant `name` (module docstring)."""
    net = base.network
    if name == "coop_lossy":
        net = replace(net, **LOSSY)
    if name == "gnss_ekf":
        return replace(base, sensors=replace(base.sensors, uwb=None), network=net,
                       estimators=(EstimatorSpec(entry="coop.ins", name=EKF),),
                       control=replace(base.control, feedback=f"estimate:{EKF}", release_sigmas=0.0, release_blend_s=0.0))
    coop = EstimatorSpec(entry=COOP_ENTRY[name], name=COOP,
                         params={} if name in ("truth", "coop", "window") else {"network": to_dict(net)})
    feedback = "truth" if name == "truth" else f"estimate:{COOP}"
    attitude = "estimate" if name == "coop_onboard" else base.control.attitude
    distributed = COOP_ENTRY[name] == "coop.ins_distributed"
    release, blend = (base.control.release_sigmas, base.control.release_blend_s) if distributed else (0.0, 0.0)
    return replace(base, network=net, estimators=(coop,), control=replace(
        base.control, feedback=feedback, attitude=attitude, release_sigmas=release, release_blend_s=blend))


def flight(run_dir: Path, metrics: dict, estimator: str) -> dict:
    """The flight metrics of one run (module docstring): tracking from its log, safety from its
    metrics.json's `flight` (testbed.scoring.safety); estimator: the key of the estimator whose position
    RMSE is the estimation error."""
    log = load_log(run_dir)
    err = np.linalg.norm(log["truth/pos"] - log["reference/pos"], axis=-1)  # (T, N) m
    safe = metrics["flight"]
    no_fix = np.array(safe["no_fix_s"])  # (N,) s
    est = metrics["estimators"][estimator]
    return {"tracking_rms_m": float(np.sqrt(np.mean(err ** 2))), "tracking_max_m": float(err.max()),
            "estimation_rmse_m": float(est["rmse_position_mean_m"]), "min_separation_m": safe["min_separation_m"],
            **{f"contacts_{k}": c["events"] for k, c in safe["contacts"].items()},
            "crashed": len(safe["crash"]["vehicles"]), "no_fix_mean_s": float(no_fix.mean()),
            "no_fix_max_s": float(no_fix.max()), "no_fix_s": no_fix.tolist(), "health": est.get("health", {})}


@dataclass(frozen=True, kw_only=True, slots=True)
class DeniedResults:
    """compute's output: base scenario, runs, {variant: [flight metrics of run i]}, {variant: [the
    metrics.json `estimators` of run i]} and the plugin estimators' names (--estimator)."""

    scenario: Scenario
    runs: int
    flights: dict[str, list[dict]]
    estimators: dict[str, list[dict]] = field(default_factory=dict)
    keys: tuple[str, ...] = ()

    def column(self, v: str, key: str) -> np.ndarray:
        """(runs,) values of metric `key` in variant v."""
        return np.array([f[key] for f in self.flights[v]], float)


def compute(out: Path, *, runs: int, duration: float | None, workers: int | None,
            estimators: tuple = ()) -> DeniedResults:
    """Every variant's sweep into OUT/runs/<variant> and its flight metrics; estimators: plugin
    EstimatorSpecs run offline on every variant's flown logs (module docstring)."""
    base = load("coop-denied", duration=duration)
    flights, ests = {}, {}
    for v in VARIANTS:
        sc = variant(base, v)
        sc = replace(sc, estimators=sc.estimators + tuple(estimators))
        dirs = sweep_runs(sc, runs, out / "runs" / v, workers=workers)
        key = EKF if v == "gnss_ekf" else COOP
        metrics = load_metrics(dirs)
        flights[v] = [flight(d, m, key) for d, m in zip(dirs, metrics)]
        ests[v] = [m["estimators"] for m in metrics]
    return DeniedResults(scenario=base, runs=runs, flights=flights, estimators=ests,
                         keys=tuple(e.key for e in estimators))


def decide(res: DeniedResults) -> list[Claim]:
    runs = res.runs
    contacts = {v: int(sum(res.column(v, f"contacts_{k}").sum() for k in ("vehicle", "obstacle", "floor")))
                for v in VARIANTS}
    claims = []
    for v in COOPERATIVE:
        claims.append(Claim(
            id=f"{v}_flight_without_contact",
            text=f"flying on the cooperative estimate ({TITLES[v]}), no vehicle touches another, an obstacle or the floor",
            criterion=f"no contact event (vehicle-vehicle, vehicle-obstacle or vehicle-floor) in any run of the {v} variant",
            holds=contacts[v] == 0, numbers={"contacts": contacts, "runs": runs},
            summary=", ".join(f"{k}: {c}" for k, c in contacts.items()),
            test="count over every logged state of every run (nothing sampled beyond the runs)", n=runs,
            paper_value="(no paper: docs/denied.md)"))
    b = res.column("gnss_ekf", "estimation_rmse_m")
    for v in COOPERATIVE:
        a = res.column(v, "estimation_rmse_m")
        # a claim about the denied street needs a street that denied: some vehicle without a fix
        lost = max(res.column(v, "no_fix_max_s").max(), res.column("gnss_ekf", "no_fix_max_s").max())
        t = wilcoxon_paired(a, b, alternative="less", level=1 - ALPHA) if runs > 1 else None
        better = bool(np.mean(a) < np.mean(b)) if t is None else bool(np.isfinite(t.p_value) and t.p_value < ALPHA)
        claims.append(Claim(
            id=f"{v}_beats_gnss_only",
            text=f"the cooperative estimate ({TITLES[v]}) is more accurate than the GNSS-only EKF in the denied street",
            criterion=(f"one-sided Wilcoxon signed-rank over {runs} paired runs, alpha = {ALPHA}" if runs > 1
                       else "1 run: decided on the point values, no test"),
            holds=better, numbers={f"{v}_rmse_m": a.tolist(), "gnss_ekf_rmse_m": b.tolist()},
            summary=f"mean position RMSE {fmt(float(np.mean(a)))} m vs {fmt(float(np.mean(b)))} m",
            test=t.test if t else "point comparison", statistic=t.statistic if t else None,
            p_value=t.p_value if t else None, n=runs, level=1 - ALPHA if t else None,
            paper_value="(no paper: docs/denied.md)",
            not_decidable="" if lost > 0 else "no vehicle lost GNSS in these runs (0 s without a fix)"))
    return claims


FLYING = "flying"  # the figure's and tables' name of each variant's own estimator (the one flown on)


def _plugin_rmse(res: DeniedResults, v: str, key: str) -> np.ndarray:
    """(runs,) plugin key's position RMSE in variant v's runs (the same score as the variant's
    estimation_rmse_m: rmse_position_mean_m), NaN where it failed or has none."""
    return plugin_rows.column(res.estimators[v], key, "rmse_position_mean_m")


def _rows(res: DeniedResults) -> list[list]:
    return [[v] + [float(np.mean(res.column(v, k))) for k in METRICS]
            + [float(np.nanmean(x)) if np.isfinite(x := _plugin_rmse(res, v, p)).any() else None for p in res.keys]
            for v in VARIANTS]


def write(out: Path, res: DeniedResults, claims: list[Claim]) -> dict:
    """table.md, table.csv, plots/, claims.json (and table_plugins.csv, table_plugins_paired.csv
    with plugins); returns claims.json's content."""
    sc, runs = res.scenario, res.runs
    (out / "plots").mkdir(parents=True, exist_ok=True)
    rows = _rows(res)
    write_csv(out / "table.csv", ["variant", *METRICS, *(f"estimation_rmse_{p}_m" for p in res.keys)], rows)
    names = [FLYING, *res.keys]
    est = np.array([[[f["estimation_rmse_m"] for f in res.flights[v]]] + [_plugin_rmse(res, v, p) for p in res.keys]
                    for v in VARIANTS], float)  # (variants, estimators, runs)
    with np.errstate(all="ignore"):  # a plugin without a score in a variant: no bar
        stats = {"estimation_rmse_m": (names, np.nanmean(est, -1), np.nanmin(est, -1), np.nanmax(est, -1))}
    trk = np.array([[f["tracking_rms_m"] for f in res.flights[v]] for v in VARIANTS])[:, None]  # only the flown estimator flies
    stats["tracking_rms_m"] = ([FLYING], trk.mean(-1), trk.min(-1), trk.max(-1))
    for key, label in (("estimation_rmse_m", "position RMSE [m]"), ("tracking_rms_m", "tracking RMS [m]")):
        shown, mean, lo, hi = stats[key]
        grouped_bars(list(VARIANTS), shown, mean, lo, hi, out / "plots" / f"{key}.png",
                     title=f"coop-denied: {label}, mean over {runs} run(s) (bars: min-max)", ylabel=label)
    md = [f"# coop-denied: {runs} run(s) of {fmt(sc.duration)} s per variant, seeds {sc.seed}..{sc.seed + runs - 1}", "",
          "Means over the runs. Tracking: |true - reference| position; estimation: position RMSE of the estimator "
          "the controller flies on (truth variant: the cooperative estimator, scored but not fed back); contacts: "
          "events (a pair coming into contact); crashed: vehicles per run (testbed.scoring.safety's rules); no fix: seconds without a GNSS fix per vehicle (mean, max)."
          + (f" {', '.join(res.keys)} (--estimator): the same position RMSE, run offline on each variant's flown logs "
             "(it does not fly)." if res.keys else ""), ""]
    md += markdown_table(["variant", "tracking RMS m", "tracking max m", "estimation RMSE m", "min separation m",
                          "contacts veh.", "contacts obst.", "contacts floor", "crashed", "no fix mean s", "no fix max s",
                          *(f"estimation RMSE m, {p}" for p in res.keys)],
                         [[TITLES[r[0]], *r[1:]] for r in rows])
    md += ["", "Estimator health, run 0: " + "; ".join(
        f"{v}: " + ", ".join(f"{k} {x}" for k, x in res.flights[v][0]["health"].items()) for v in VARIANTS), ""]
    md += plugin_rows.markdown(res.estimators, list(res.keys), "variant")
    plugin_rows.write(out / "table_plugins.csv", res.estimators, list(res.keys))
    write_markdown(out / "table.md", md)
    return write_claims(out / "claims.json", claims, scenario=sc.name, runs=runs, seeds=seeds(sc.seed, runs),
                        duration_s=sc.duration, lossy_network=LOSSY,
                        flights={v: res.flights[v] for v in VARIANTS},
                        **({"plugins": {p: {v: [float(x) if np.isfinite(x) else None for x in _plugin_rmse(res, v, p)]
                                            for v in VARIANTS} for p in res.keys}} if res.keys else {}))


def reproduce(out: Path, *, runs: int, motion: str = "flown", duration: float | None = None,
              workers: int | None = None, estimators: tuple = ()) -> dict:
    """The denied-street experiment into `out` (module docstring); returns claims.json's content.
    motion: flown only (the variants differ in what the controller flies on); estimators: plugin
    EstimatorSpecs scored offline on every variant's flights (module docstring)."""
    if motion != "flown":
        raise UsageError(f"reproduce denied: the variants differ in what the controller flies on; --motion must be "
                         f"flown, got {motion}")
    out = Path(out)
    res = compute(out, runs=runs, duration=duration, workers=workers, estimators=estimators)
    return write(out, res, decide(res))
