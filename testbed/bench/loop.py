"""`testbed bench loop [--vehicles 1,10,30]`: cost of an estimator in the control loop.

Per swarm size (the benchmark swarm of testbed.bench.swarm, IMU 100 Hz, GNSS 5 Hz, UWB to four
anchors 10 Hz), the same flown run three ways, CPU seconds (time.process_time: the machine may
be shared) per simulated second:
  truth  [control] feedback = "truth" (the sensors apply their errors in batch at the end);
  hold   feedback = "estimate:hold", a do-almost-nothing estimator (each GNSS fix minus its lever
         arm as the position): the cost of the online feed itself (rows to Measurements, queue,
         delivery, checking and collecting estimates, the controller's inputs);
  eskf   feedback = "estimate:nav.eskf", the built-in filter (its own per-measurement cost on top).
Also: measurements fed, and the feed's overhead per measurement, (hold - truth) / fed, in
microseconds. The feed is linear in the measurements (one heap push and pop each), so that
figure must stay flat across sizes and durations (`duration_scale` repeats the smallest size
at twice the duration).
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from testbed.bench.swarm import swarm_scenario
from testbed.plugins.api import Estimate
from testbed.plugins.context import make_context
from testbed.plugins.loading import Plugin, load_class
from testbed.plugins.online import OnlineEstimator
from testbed.config.estimators import EstimatorSpec
from testbed.config.scenario import Scenario
from testbed.sim.simulate import simulate
from testbed.sim.world import build, lever_arms

SIZES = (1, 10, 30)
SENSORS = {
    "imu": {"preset": "bmi088", "rate_hz": 100.0},
    "gnss": {"rate_hz": 5.0},
    "uwb": {"preset": "dw1000", "rate_hz": 10.0, "anchor_links": True},
}
WORLD = {"anchors": [[0.0, 0.0, 2.0], [200.0, 0.0, 2.0], [0.0, 200.0, 2.0], [200.0, 200.0, 2.0]]}


class Hold:
    """Each GNSS fix minus the antenna's lever arm (attitude ignored) as its vehicle's position."""

    def __init__(self, context, params):
        self.sites = context.sites

    def process(self, m):
        if m.stream != "gnss":
            return []
        body, arm = self.sites[m.src]
        return [Estimate(time=m.time, target=body, quantity="position", value=m.value - arm)]


def _scenario(n: int, duration: float, name: str) -> Scenario:
    sc = swarm_scenario(n, duration, spacing=(60.0, 60.0, 50.0), origin=(40.0, 40.0, 25.0), sensors=SENSORS, world=WORLD)
    if name == "truth":
        return sc
    return dataclasses.replace(sc, estimators=(EstimatorSpec(entry=name, name=name),),
                               control=dataclasses.replace(sc.control, feedback=f"estimate:{name}"))


def _cpu(sc: Scenario, cls: type | None) -> tuple[float, int]:
    """(CPU s, measurements fed) of one flown run, the scene built outside the timing."""
    physics = build(sc)
    online = None
    if cls is not None:
        spec = sc.estimators[0]
        online = OnlineEstimator(sc, Plugin(spec.key, spec.entry, cls), make_context(sc, lever_arms(physics), spec.key, {}))
    c = time.process_time()
    simulate(sc, physics, feedback=online)
    if online is not None:
        online.finish()
    return time.process_time() - c, (online.fed if online is not None else 0)


def bench_loop(sizes=SIZES, duration: float = 10.0) -> dict:
    """Rows per size: vehicles, duration_s, truth / hold / eskf CPU seconds per simulated
    second, measurements fed, feed_us_per_measurement; and the smallest size at 2x duration."""
    eskf = load_class("nav.eskf")
    rows = []
    for n in sizes:
        truth, _ = _cpu(_scenario(n, duration, "truth"), None)
        hold, fed = _cpu(_scenario(n, duration, "hold"), Hold)
        nav, _ = _cpu(_scenario(n, duration, "nav.eskf"), eskf)
        rows.append({"vehicles": n, "duration_s": duration, "truth_cpu_s_per_s": truth / duration,
                     "hold_cpu_s_per_s": hold / duration, "eskf_cpu_s_per_s": nav / duration, "measurements": fed,
                     "feed_us_per_measurement": 1e6 * (hold - truth) / max(fed, 1)})
    n = sizes[0]
    truth, _ = _cpu(_scenario(n, 2 * duration, "truth"), None)
    hold, fed = _cpu(_scenario(n, 2 * duration, "hold"), Hold)
    scale = {"vehicles": n, "duration_s": 2 * duration, "measurements": fed,
             "feed_us_per_measurement": 1e6 * (hold - truth) / max(fed, 1)}
    return {"rows": rows, "duration_scale": scale, "growth_exponent_hold": _exponent(rows)}


def _exponent(rows: list[dict]) -> float | None:
    """b of CPU (hold) ~ N^b over the sizes (None with fewer than two)."""
    if len(rows) < 2:
        return None
    n = np.array([r["vehicles"] for r in rows], float)
    c = np.array([r["hold_cpu_s_per_s"] for r in rows])
    return float(np.polyfit(np.log(n), np.log(c), 1)[0])
