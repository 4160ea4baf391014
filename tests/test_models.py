"""The MJCF models (models/*.xml) and every scene the package builds from them.

Every scene: each built-in scenario in both motion modes, the physics benchmark's swarms at small
N (one vehicle, one digit, two digits: the decimal attach blocks of testbed.sim.world), and the
sensor benchmark's swarm (anchors and obstacles). Each is built and simulated briefly; any MuJoCo
warning fails: compiler messages (MjSpec.compile reports them with warnings.warn), messages
through mju_user_warning, and the `data.warning` counters at the end.
"""
import warnings

import mujoco
import numpy as np
import pytest

from testbed.config import scenario
from testbed.bench.sensors import arena_swarm
from testbed.bench.swarm import swarm_scenario
from testbed.reference import GRAVITY
from testbed.sim.simulate import simulate
from testbed.sim.world import MODELS, _attach, _attach_vehicles, _vehicle_spec, _vehicle_template, build

SHORT_S = 0.2  # s of simulation per scene: enough for every sensor to sample and the controller to act
VISUAL, COLLISION, ENVIRONMENT = 2, 3, 0  # geom groups (docs/models.md)


def _scenes() -> dict[str, "scenario.Scenario"]:
    scenes = {f"{name}/{motion}": scenario.load(name, {}, motion=motion, duration=SHORT_S)
              for name in scenario.builtin_names() for motion in ("prescribed", "flown")}
    scenes.update({f"bench-swarm-{n}": swarm_scenario(n, SHORT_S) for n in (1, 6, 12)})
    scenes["sensor-bench-swarm"] = arena_swarm(SHORT_S, {"imu": {}, "gnss": {}, "uwb": {"max_range": 100.0}})
    return scenes


SCENES = _scenes()


@pytest.fixture
def mujoco_messages():
    """Messages MuJoCo sends through mju_user_warning while the test runs."""
    messages: list[str] = []
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(messages.append)
    yield messages
    mujoco.set_mju_user_warning(previous)


@pytest.mark.parametrize("key", sorted(SCENES))
def test_every_scene_builds_and_simulates_without_mujoco_warnings(key, mujoco_messages):
    with warnings.catch_warnings(record=True) as compiler:
        warnings.simplefilter("always")
        physics = build(SCENES[key])
        _, physics = simulate(SCENES[key], physics)
    assert [str(w.message) for w in compiler] == []
    assert mujoco_messages == []
    assert physics.warnings() == {}
    assert physics.time > 0 or SCENES[key].motion == "prescribed"


@pytest.mark.parametrize("key", sorted(SCENES))
def test_geom_groups_follow_the_convention(key):
    """Vehicles: colliding geoms in group 3 (seen by rays: alpha > 0), the others in group 2.
    World body: colliding geoms (floor, obstacles) in group 0, the others (anchor masts) in 2."""
    m = build(SCENES[key]).model
    colliding = (m.geom_contype != 0) | (m.geom_conaffinity != 0)
    on_vehicle = m.geom_bodyid != 0
    expected = np.where(colliding, np.where(on_vehicle, COLLISION, ENVIRONMENT), VISUAL)
    wrong = [(m.geom(g).name or f"geom {g} of body {m.body(m.geom_bodyid[g]).name}", int(m.geom_group[g]))
             for g in np.flatnonzero(m.geom_group != expected)]
    assert wrong == []
    assert colliding[on_vehicle].any() and (~colliding[on_vehicle]).any()
    alpha = np.where(m.geom_matid >= 0, m.mat_rgba[m.geom_matid, 3], m.geom_rgba[:, 3])
    assert np.all(alpha[colliding] > 0), "collision geoms must be visible to mj_ray (alpha > 0)"


def test_quadrotor_model_conventions():
    """Root default class named after the model, rotors as motors on their sites, hover keyframe."""
    spec = mujoco.MjSpec.from_file(str(MODELS / "quadrotor.xml"))
    assert spec.modelname == "quadrotor"
    assert spec.find_default("quadrotor") is not None
    assert spec.body("base").childclass == "quadrotor"
    m = spec.compile()
    rotors = [m.actuator(f"rotor{k}") for k in range(1, 5)]
    assert all(a.trntype[0] == mujoco.mjtTrn.mjTRN_SITE and m.site(a.trnid[0]).name == a.name for a in rotors)
    # <motor>: force = ctrl (gain 1, no bias, no activation dynamics)
    assert np.all(m.actuator_gaintype == mujoco.mjtGain.mjGAIN_FIXED) and np.all(m.actuator_gainprm[:, 0] == 1)
    assert np.all(m.actuator_biastype == mujoco.mjtBias.mjBIAS_NONE) and np.all(m.actuator_dyntype == mujoco.mjtDyn.mjDYN_NONE)
    assert m.key("hover") is not None
    # the mass and inertia are those of <inertial> alone (docs/models.md: kg, kg m^2)
    assert m.body("base").mass[0] == 6.9
    np.testing.assert_array_equal(m.body("base").inertia, [0.45, 0.35, 0.75])


def test_hover_keyframe_hovers():
    """At the hover keyframe the four thrusts carry the weight and the rotor torques cancel."""
    m = mujoco.MjModel.from_xml_path(str(MODELS / "quadrotor.xml"))
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("hover").id)
    mujoco.mj_forward(m, d)
    assert m.opt.gravity[2] == pytest.approx(-GRAVITY)
    np.testing.assert_allclose(d.qacc, 0.0, atol=1e-3)  # m/s^2, rad/s^2: ctrl rounded to 1 mN


@pytest.mark.parametrize("n", [9, 23, 123])
def test_block_attach_compiles_to_the_one_by_one_scene(n):
    """testbed.sim.world attaches vehicles in decimal blocks: the compiled model is the one of
    attaching uav1/ .. uav{n}/ one by one, and its saved XML loads back to the same model."""
    sc = swarm_scenario(n, SHORT_S)
    template = _vehicle_template(sc)
    blocks, flat = (mujoco.MjSpec.from_file(str(MODELS / "arena.xml")) for _ in range(2))
    _attach_vehicles(blocks, template, n)
    for i in range(1, n + 1):
        _attach(flat, _vehicle_spec(template, i), f"uav{i}/")
    a, b = blocks.compile(), flat.compile()
    reloaded = mujoco.MjModel.from_xml_string(blocks.to_xml())
    for other, tol in ((b, 0.0), (reloaded, 1e-6)):  # MjSpec.to_xml prints derived sizes to ~6 digits
        for obj, count in (("body", a.nbody), ("geom", a.ngeom), ("site", a.nsite), ("actuator", a.nu),
                           ("sensor", a.nsensor), ("camera", a.ncam), ("material", a.nmat)):
            assert [getattr(a, obj)(i).name for i in range(count)] == [getattr(other, obj)(i).name for i in range(count)]
        for field in ("body_pos", "body_mass", "body_inertia", "geom_pos", "geom_size", "geom_group", "geom_rgba",
                      "site_pos", "actuator_gear", "actuator_trnid", "sensor_adr", "jnt_qposadr", "mat_rgba"):
            np.testing.assert_allclose(getattr(a, field), getattr(other, field), rtol=0, atol=tol, err_msg=field)
    assert [a.body(i).name for i in range(1, n + 1)] == [f"uav{i}/base" for i in range(1, n + 1)]
