"""`testbed bench swarm-loop`'s scenario (testbed.bench.swarm_loop): swarm-100 with everything
coop-denied flies on, flown on coop.ins_distributed; a small copy of it flies with every vehicle
on its estimate's loop (the bench itself measures speed; this checks what it flies)."""
from __future__ import annotations

import numpy as np

from testbed.bench.swarm_loop import swarm_loop_scenario
from testbed.config import to_dict
from testbed.config.scenario import load
from testbed.plugins.loading import resolve
from testbed.plugins.online import in_the_loop
from testbed.sim.simulate import simulate
from testbed.sim.world import build


def test_the_swarm_loop_bench_flies_swarm_100_on_the_distributed_filter_as_coop_denied_does():
    sc, denied = swarm_loop_scenario(), load("coop-denied")
    assert sc.vehicles == 100 and sc.motion == "flown"
    assert sc.sensors.imu is not None and sc.sensors.gnss is not None and sc.sensors.uwb is not None
    assert to_dict(sc.network) == to_dict(denied.network)
    (est,) = sc.estimators
    assert est.entry == "coop.ins_distributed" and est.params["network"] == to_dict(denied.network)
    c = sc.control
    assert c.feedback == f"estimate:{est.name}" and c.attitude == "truth"
    assert (c.max_tilt_deg, c.release_sigmas) == (denied.control.max_tilt_deg, denied.control.release_sigmas)


def test_a_small_swarm_loop_flies_every_vehicle_on_its_estimate():
    """9 vehicles in a row, 1.5 s: every vehicle has a position estimate (first fixes at 0.2 s);
    the two ends of the row (the formation's corners, RTK: centimetre fixes) are released from
    their reference by the initialization phase; the broadcasts travel the network."""
    sc = swarm_loop_scenario(duration=1.5, vehicles=9)
    physics = build(sc)
    online = in_the_loop(sc, physics, resolve(sc.estimators))
    log, _ = simulate(sc, physics, feedback=online)
    _, health, _ = online.finish()
    assert online.has[0].all() and online.released[[0, 8]].all()
    assert health["sent"] > 0 and health["delivered"] > 0
    err = np.linalg.norm(log["truth/pos"] - log["reference/pos"], axis=-1)
    assert np.isfinite(err).all()
