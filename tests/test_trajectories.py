"""The trajectory library (testbed/trajectories.py, the kinds of testbed/config/scenario.py): minimum-snap
splines pass their waypoints, are continuous through them (position to snap imposed, 5th and 6th
derivatives by optimality) and are the QP's optimum; the airframe's limits refuse a reference at
load (one line, exit 2); every kind evaluates to finite values of the right shapes; a short
flown run tracks a spline within the lag its controller predicts."""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import get_args, get_type_hints

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from testbed import trajectories
from testbed.cli import main
from testbed.errors import ConfigError
from testbed.reference import evaluate
from testbed.config.scenario import Circle, Lemniscate, Spline, Trajectory, builtin_names, load

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples" / "trajectories").glob("*.toml"))
PROPERTY = settings(max_examples=40, derandomize=True, database=None, deadline=None, suppress_health_check=[HealthCheck.too_slow])
FIG8 = ((0.0, 0.0, 10.0), (8.0, 6.0, 10.0), (16.0, 0.0, 10.0), (8.0, -6.0, 10.0), (0.0, 0.0, 10.0),
        (-8.0, 6.0, 10.0), (-16.0, 0.0, 10.0), (-8.0, -6.0, 10.0))
EPS = 1e-7  # s: one-sided limits at a waypoint are taken at t -/+ EPS


def _jumps(path: trajectories.PiecewisePolynomial, orders: int) -> np.ndarray:
    """(orders, joints): |left - right| limits of d^r p/dt^r at every joint of `path` (the interior
    knots; a closed path also its start), exact from the coefficients (S1)."""
    T = np.diff(path.knots)
    S = len(T)
    joints = range(S) if path.closed else range(S - 1)
    k = np.arange(trajectories.DEGREE + 1)
    out = np.zeros((orders, len(joints)))
    for col, i in enumerate(joints):
        j = (i + 1) % S
        for r in range(orders):
            f = np.prod([np.clip(k - q, 0, None) for q in range(r)], axis=0) if r else np.ones(len(k))
            left = (f[:, None] * path.coeffs[i]).sum(0) / T[i] ** r  # s = 1
            right = math.factorial(r) * path.coeffs[j][r] / T[j] ** r  # s = 0
            out[r, col] = np.linalg.norm(left - right)
    return out


def _scale(path: trajectories.PiecewisePolynomial, orders: int) -> np.ndarray:
    """(orders,) the largest |d^r p/dt^r| along the path: the size a jump is compared with."""
    t = np.linspace(0, path.knots[-1], 4001)
    return np.linalg.norm(path.derivatives(t, orders), axis=-1).max(axis=1)


# ------------------------------------------------------------------------ minimum snap


@pytest.mark.parametrize("closed", [False, True])
def test_spline_passes_its_waypoints_at_their_times(closed):
    tr = Spline(kind="spline", points=FIG8, closed=closed, speed=4.0, offsets=((0.0, 0.0, 0.0), (1.0, 2.0, 3.0)))
    knots = tr.path.knots
    ref = evaluate(tr, knots, rates=False)
    want = np.array(FIG8 + (FIG8[0],) if closed else FIG8)
    assert np.abs(ref.pos[:, 0] - want).max() < 1e-9
    assert np.abs(ref.pos[:, 1] - want - (1.0, 2.0, 3.0)).max() < 1e-9


@pytest.mark.parametrize("closed", [False, True])
def test_position_velocity_and_acceleration_are_continuous_through_the_waypoints(closed):
    """Numerically, from evaluate at t -/+ EPS: a continuous quantity changes by about
    2 EPS |its derivative| there (bounded with the derivative's largest value along the path); a
    jump of the size of the quantity's scale would be 1e6 times that."""
    tr = Spline(kind="spline", points=FIG8, closed=closed, speed=4.0)
    knots = tr.path.knots[1:-1]
    lo, hi = evaluate(tr, knots - EPS), evaluate(tr, knots + EPS)
    scale = _scale(tr.path, 4)
    for r, (a, b) in enumerate([(lo.pos, hi.pos), (lo.vel, hi.vel), (lo.acc, hi.acc)]):
        jump = np.linalg.norm(a - b, axis=-1).max()
        assert jump <= 2 * EPS * scale[r + 1] * (1 + 1e-3) + 1e-12, (r, jump)
    # the flat attitude and body rate (from the acceleration and jerk) are continuous too
    assert np.linalg.norm(lo.omega - hi.omega, axis=-1).max() < 1e-4


def test_the_jump_measure_sees_a_velocity_jump():
    """The check above can fail: the same spline with one segment's linear coefficient moved by
    1 mm (a velocity step at its ends) shows jumps in velocity, not in position."""
    path = Spline(kind="spline", points=FIG8, closed=True, speed=4.0).path
    spoiled = trajectories.PiecewisePolynomial(path.knots, path.coeffs.copy(), True)
    spoiled.coeffs[2, 1, 0] += 1e-3
    jumps = _jumps(spoiled, 2)
    assert jumps[0, 2] > 1e-4 and jumps[1].max() > 1e-4  # the end of segment 2 moved, and its slope
    assert _jumps(path, 2).max() < 1e-9


@pytest.mark.parametrize("closed", [False, True])
def test_snap_is_continuous_by_constraint_and_the_5th_and_6th_derivatives_by_optimality(closed):
    """(S4) imposes derivatives 1..4; the optimum of (S2) is also C^6 (Euler-Lagrange), a
    property of the solution that a wrong cost or a wrong solve would not have. Compared with
    each derivative's largest value along the path."""
    path = Spline(kind="spline", points=FIG8, closed=closed, speed=4.0).path
    rel = _jumps(path, 7).max(axis=1) / _scale(path, 7)
    assert rel[:5].max() < 1e-9, rel
    assert rel[5:].max() < 1e-6, rel
    # not C^7: the 7th derivative jumps (the check is not vacuous)
    seventh = _jumps(path, 8)[7].max()
    assert seventh > 1e-3 * np.abs(path.coeffs[:, 7]).max() * math.factorial(7) / np.diff(path.knots).max() ** 7


@PROPERTY
@given(st.integers(2, 6), st.booleans(), st.integers(0, 2**32 - 1), st.booleans())
def test_the_spline_is_the_qp_optimum_through_random_waypoints(m, closed, seed, given_times):
    """Random waypoints in a 40 m box, times given or allocated: the constraints hold (A c = b)
    and every feasible direction (the null space of A) raises the snap cost; the waypoints are
    passed; an open path starts and ends at rest."""
    rng = np.random.default_rng(seed)
    P = rng.uniform([-20, -20, 5], [20, 20, 25], size=(m, 3))
    assume(np.linalg.norm(np.diff(np.vstack([P, P[:1]]), axis=0), axis=1).min() > 1.0)
    T = rng.uniform(2.0, 10.0, size=m if closed else m - 1) if given_times else trajectories.allocate(P, 3.0, closed)
    path = trajectories.min_snap(P, T, closed)
    Q, A, b = trajectories.snap_qp(P, T, closed)
    c = path.coeffs.reshape(-1, 3)
    assert np.abs(A @ c - b).max() < 1e-8 * max(1.0, np.abs(b).max())
    _, sv, vt = np.linalg.svd(A)
    null = vt[(sv > 1e-10 * sv[0]).sum():]
    assert len(null) == len(c) - len(A) or (not closed and m == 2 and len(null) == 0)  # one open segment: no freedom
    cost = np.einsum("ia,ij,ja->a", c, Q, c)
    for z in null[rng.choice(len(null), size=min(5, len(null)), replace=False)]:
        for eps in (1e-3, -1e-3):
            moved = c + eps * z[:, None] * np.abs(c).max()
            assert (np.einsum("ia,ij,ja->a", moved, Q, moved) >= cost * (1 - 1e-9)).all()
    assert np.abs(path.derivatives(path.knots, 1)[0] - (np.vstack([P, P[:1]]) if closed else P)).max() < 1e-7
    if not closed:
        ends = path.derivatives(np.array([0.0, path.knots[-1]]), 4)[1:]
        assert np.abs(ends).max() < 1e-8


def test_time_allocation_follows_the_stated_rule():
    P = np.array([[0.0, 0, 5], [8.0, 0, 5], [8.0, 0, 5], [8.0, 6, 5]])
    assert np.allclose(trajectories.allocate(P, 4.0, closed=False), [4.0, 0.5, 3.0])  # 2 x 2 s, pause, 2 x 1.5 s
    assert np.allclose(trajectories.allocate(P, 4.0, closed=True), [2.0, 0.5, 1.5, 2.5])


# ----------------------------------------------------------------------------- limits


def test_airframe_limits_are_those_of_the_flown_model():
    """airframe() reads models/quadrotor.xml without MuJoCo; MuJoCo's compiled model agrees."""
    import mujoco

    model = mujoco.MjModel.from_xml_path(str(trajectories.AIRFRAME_FILE))
    af = trajectories.airframe()
    assert af.mass == pytest.approx(model.body("base").mass[0], rel=1e-12)
    assert af.max_thrust == pytest.approx(model.actuator_ctrlrange[:, 1].sum(), rel=1e-12)
    assert af.rotors == model.nu == 4


def _circle_ok(radius: float, period: float) -> bool:
    """The closed form of the circle's limits: speed 2 pi R / P, thrust per mass sqrt((R w^2)^2 + g^2)."""
    af, w = trajectories.airframe(), 2 * math.pi / period
    return radius * w <= af.max_speed and math.hypot(radius * w * w, trajectories.GRAVITY) <= af.max_accel


@PROPERTY
@given(st.floats(1.0, 200.0), st.floats(0.5, 200.0))
def test_a_circle_loads_exactly_when_the_airframe_can_fly_it(radius, period):
    w = 2 * math.pi / period
    af = trajectories.airframe()
    margin = min(abs(radius * w / af.max_speed - 1), abs(math.hypot(radius * w * w, trajectories.GRAVITY) / af.max_accel - 1))
    assume(margin > 1e-6)
    try:
        Circle(kind="circle", center=(0.0, 0.0, 50.0), radius=radius, period=period)
        loaded = True
    except ConfigError as e:
        assert e.key == "period" and f"{period:g}" in str(e)
        loaded = False
    assert loaded == _circle_ok(radius, period)


def test_limits_name_the_key_that_sets_them():
    too_fast = dict(kind="spline", points=((0.0, 0.0, 5.0), (100.0, 0.0, 5.0), (200.0, 0.0, 5.0)))
    with pytest.raises(ConfigError, match=r"^speed: 30: the reference reaches .* m/s .* faster than the airframe's 23 m/s"):
        Spline(**too_fast, speed=30.0)
    Spline(**too_fast, speed=10.0)  # the same path at a cruise speed the airframe flies
    short = ((0.0, 0.0, 5.0), (5.0, 0.0, 5.0), (10.0, 0.0, 5.0))
    with pytest.raises(ConfigError, match=r"^times: \[0.0, 1.0, 2.0\]: the reference needs .* m/s\^2 of thrust per unit mass"):
        Spline(kind="spline", points=short, times=(0.0, 1.0, 2.0))
    Spline(kind="spline", points=short, times=(0.0, 2.0, 4.0))
    with pytest.raises(ConfigError, match=r"^period: 4: .* thrust per unit mass"):
        Lemniscate(kind="lemniscate", center=(0.0, 0.0, 20.0), size=(10.0, 5.0), period=4.0)
    # downwards faster than gravity within thrust and speed (thrust cannot pull down): the rule itself,
    # since a rest-to-rest path that does it needs more thrust on the way back up
    t = np.array([0.0, 1.0])
    acc = np.array([[0.0, 0.0, -5.0], [0.0, 0.0, -12.0]])
    assert trajectories.limit_violation(t, np.zeros((2, 3)), acc).startswith("the reference accelerates downwards at 12.0 m/s^2 at t = 1.00 s")
    assert trajectories.limit_violation(t[:1], np.zeros((1, 3)), acc[:1]) is None


@pytest.mark.parametrize("table, key", [
    ('kind = "circle"\ncenter = [0.0, 0.0, 20.0]\nradius = 10.0\nperiod = 3.0', "trajectory.period: 3"),
    ('kind = "spline"\npoints = [[0.0, 0.0, 5.0], [100.0, 0.0, 5.0]]\nspeed = 40.0', "trajectory.speed: 40"),
    ('kind = "spline"\npoints = [[0.0, 0.0, 5.0], [10.0, 0.0, 5.0]]\ntimes = [0.0, 0.5]', "trajectory.times: [0.0, 0.5]"),
])
def test_a_trajectory_beyond_the_airframe_exits_2_with_one_line(table, key, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    Path("fast.toml").write_text(f'name = "fast"\ndescription = "too fast"\nduration = 2.0\nmotion = "flown"\n[trajectory]\n{table}\n')
    assert main(["run", "./fast.toml", "--out", "out"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"testbed: error: ./fast.toml: {key}: "), lines
    assert sorted(os.listdir(tmp_path)) == ["fast.toml"]


# ---------------------------------------------------------------------------- every kind


def _every_kind() -> list[str]:
    """One scenario per trajectory kind: the built-ins and examples/trajectories/*.toml."""
    seen, out = set(), []
    for name in [*builtin_names(), *map(str, EXAMPLES)]:
        kind = load(name).trajectory.kind
        if kind not in seen:
            seen.add(kind)
            out.append(name)
    return out


KINDS = _every_kind()


def test_every_kind_has_a_scenario_and_a_picture():
    kinds = {get_args(get_type_hints(c)["kind"])[0] for c in get_args(Trajectory)}
    assert {load(name).trajectory.kind for name in KINDS} == kinds and len(kinds) == 10
    doc = (ROOT / "docs" / "scenario.md").read_text()
    for kind in kinds:
        picture = f"images/trajectory-{kind}.png"
        assert f"]({picture})" in doc and (ROOT / "docs" / picture).is_file(), kind


@pytest.mark.parametrize("name", KINDS, ids=lambda n: Path(n).stem)
def test_every_kind_evaluates_to_finite_values_of_the_right_shapes(name):
    sc = load(name)
    t = np.concatenate([[-0.5, 0.0], np.linspace(0.0, sc.duration, 9), [sc.duration + 3.0]])
    ref = evaluate(sc.trajectory, t)
    K, N = len(t), sc.vehicles
    for a in (ref.pos, ref.vel, ref.acc, ref.omega, ref.alpha):
        assert a.shape == (K, N, 3) and np.isfinite(a).all()
    assert ref.quat.shape == (K, N, 4) and np.allclose(np.linalg.norm(ref.quat, axis=-1), 1.0)
    assert ref.yaw.shape == (K, N) and np.isfinite(ref.yaw).all()


@pytest.mark.parametrize("name", [str(p) for p in EXAMPLES], ids=lambda n: Path(n).stem)
def test_examples_load_and_their_paths_are_clear(name):
    from testbed.reference import clearance

    sc = load(name)
    assert clearance(sc) is None


@pytest.mark.parametrize("kind", ["circle", "lemniscate"])
def test_curve_formations_spread_vehicles_in_phase_and_layers(kind):
    extra = {"radius": 10.0} if kind == "circle" else {"size": (10.0, 6.0)}
    cls = Circle if kind == "circle" else Lemniscate
    tr = cls(kind=kind, center=(0.0, 0.0, 20.0), period=20.0, count=4, layer=2.0, **extra)
    t = np.linspace(0, 20.0, 201)
    one = cls(kind=kind, center=(0.0, 0.0, 20.0), period=20.0, **extra)
    pos, ref = evaluate(tr, t, rates=False).pos, evaluate(one, t, rates=False).pos[:, 0]
    for i in range(4):  # vehicle i is vehicle 0 a quarter period i later, i layers higher
        later = evaluate(one, t + 5.0 * i, rates=False).pos[:, 0]
        assert np.abs(pos[:, i] - later - (0.0, 0.0, 2.0 * i)).max() < 1e-9
    assert np.abs(pos[:, 0] - ref).max() < 1e-12
    # velocity and acceleration are the derivatives of position (central differences)
    h = 1e-4
    p0, p1 = evaluate(tr, t - h, rates=False), evaluate(tr, t + h, rates=False)
    mid = evaluate(tr, t, rates=False)
    assert np.abs((p1.pos - p0.pos) / (2 * h) - mid.vel).max() < 1e-6
    assert np.abs((p1.vel - p0.vel) / (2 * h) - mid.acc).max() < 1e-6


# ------------------------------------------------------------------------------- flown


def test_a_flown_spline_tracks_its_reference():
    """4 s flown on the figure-eight spline (two vehicles). The Lee controller has no angular-rate
    feed-forward (testbed/sim/control.py: moment -kr e_R - kw omega), so a thrust axis turning at
    omega ~ |jerk| / |a + g| lags it by kw omega / kr in steady state: an acceleration error
    jerk kw / kr, which the position loop turns into a position error jerk kw / (kr kx) (its
    static gain 1 / kx; kv = 3, kx = 4 give damping 0.75, no overshoot to speak of). The RMS
    error must stay below that worst-case lag at the path's largest jerk."""
    from testbed.runner import tracking_rmse
    from testbed.sim.simulate import simulate

    sc = load(str(ROOT / "examples/trajectories/spline.toml"), duration=4.0)
    t = np.linspace(0.0, 4.0, 4001)
    jerk = np.linalg.norm(sc.trajectory.path.derivatives(t, 4)[3], axis=-1).max()
    bound = jerk * sc.control.kw / (sc.control.kr * sc.control.kx)
    log, _ = simulate(sc)
    rmse = tracking_rmse(log)
    assert len(rmse) == 2 and max(rmse) < bound, (rmse, bound)
    travelled = np.linalg.norm(np.diff(log["truth/pos"][:, 0], axis=0), axis=-1).sum()
    assert travelled > 10.0  # it did fly the path (about 4 m/s for 4 s)
