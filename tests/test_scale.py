"""Large-swarm machinery: MuJoCo sensors evaluated only where read, the streamed log."""
from __future__ import annotations

import mujoco
import numpy as np

from testbed.bench.swarm import swarm_scenario
from testbed.log import LogWriter, load_log, save_npz
from testbed.sim.simulate import simulate
from testbed.sim.world import build


def test_flown_imu_reads_the_sensors_of_its_own_tick_and_model_flags_are_restored():
    """MuJoCo's sensors run only at the IMU's ticks: the clean IMU equals a fresh mj_forward of
    the logged state (same accelerometer and gyro as with sensors always on), and the model's
    disable flags are as before the run."""
    sc = swarm_scenario(3, 0.2, sensors={"imu": {"rate_hz": 100.0}})
    physics = build(sc)
    flags = physics.model.opt.disableflags
    log, physics = simulate(sc, physics)
    assert physics.model.opt.disableflags == flags
    m, d = physics.model, mujoco.MjData(physics.model)
    idx = np.searchsorted(log["time"], log["imu/time"])
    assert len(idx) > 10
    for row in idx[:: max(1, len(idx) // 5)]:
        d.qpos[:], d.qvel[:], d.ctrl[:] = log["qpos"][row], log["qvel"][row], log["ctrl"][row]
        mujoco.mj_forward(m, d)
        step = np.flatnonzero(idx == row)
        clean = log["imu/clean"][step]
        np.testing.assert_allclose(clean, d.sensordata[physics.imu_idx], rtol=0, atol=1e-9)
        assert np.abs(clean[:, :3]).max() > 5.0  # specific force of hover, not stale zeros


def _pieces(rng: np.random.Generator, n: int) -> list[tuple[str, np.ndarray]]:
    """n appended pieces of three keys: float rows (R, 3), int rows, names of growing width."""
    out = []
    for k in range(n):
        r = int(rng.integers(0, 40))
        out += [("a/value", rng.standard_normal((r, 3))), ("a/index", rng.integers(0, 9, r)),
                ("a/src", np.array([f"uav{i * 10 ** (k % 4)}/uwb" for i in range(r)], dtype=str))]
    return out


def test_spilled_log_saves_the_same_bytes_as_the_whole_arrays(tmp_path):
    """A LogWriter spilling to chunk files every few kB writes log.npz byte-identical to
    save_npz of the concatenated arrays, reads back equal, and leaves no chunk behind."""
    pieces = _pieces(np.random.default_rng(3), 60)
    spill = tmp_path / "chunks"
    w = LogWriter(spill, spill_bytes=2048)
    for key, rows in pieces:
        w.append(key, rows)
    w.put("b/whole", np.arange(12.0).reshape(3, 4).T)  # a Fortran-ordered whole array
    assert len(list(spill.iterdir())) > 10  # it did spill
    whole = {key: np.concatenate([r for k, r in pieces if k == key]) for key in ("a/value", "a/index", "a/src")}
    whole["b/whole"] = np.arange(12.0).reshape(3, 4).T
    assert whole["a/src"].dtype == np.dtype("U12")
    w.save(tmp_path / "streamed.npz")
    save_npz(tmp_path / "whole.npz", whole)
    assert (tmp_path / "streamed.npz").read_bytes() == (tmp_path / "whole.npz").read_bytes()
    back = load_log(tmp_path / "streamed.npz")
    for key, value in whole.items():
        np.testing.assert_array_equal(back[key], value)
        assert back[key].dtype == value.dtype
    w.close()
    assert not spill.exists()


def test_log_writer_memory_stays_bounded_while_the_log_grows(tmp_path):
    """Appending 64 MB in 1 MB pieces with spill_bytes = 2 MB: the traced peak stays below
    three pieces above the spill threshold (twice the held rows while one chunk is written),
    not the 64 MB an in-memory log holds."""
    import tracemalloc

    piece, spill_bytes = 2**20, 2 * 2**20
    w = LogWriter(tmp_path / "chunks", spill_bytes=spill_bytes)
    tracemalloc.start()
    for k in range(64):
        w.append("x", np.full((piece // 8 // 4, 4), float(k)))
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 2 * spill_bytes + 3 * piece, peak
    assert w.arrays()["x"].shape == (64 * piece // 32, 4)


def test_a_run_spilling_its_log_writes_the_log_of_the_in_memory_simulation(tmp_path, monkeypatch):
    """testbed run with chunk files every 4 kB (sensors and state rows spilled many times) writes
    the log.npz bytes of simulate()'s in-memory arrays, and no chunk file is left in the run."""
    import testbed.log
    from testbed.runner import SPILL_DIR, run

    sc = swarm_scenario(12, 1.0, sensors={"uwb": {"rate_hz": 10.0}, "gnss": {"rate_hz": 5.0}, "imu": {"rate_hz": 100.0}})
    save_npz(tmp_path / "memory.npz", simulate(sc)[0])
    spilled, close = [], testbed.log.LogWriter.close

    def count_then_close(writer):
        spilled.append(len(list(writer.spill_dir.iterdir())))
        close(writer)

    monkeypatch.setattr(testbed.log, "SPILL_BYTES", 4096)
    monkeypatch.setattr(testbed.log.LogWriter, "close", count_then_close)
    run(sc, tmp_path / "run", plots=False)
    assert spilled[0] > 20
    assert (tmp_path / "run" / "log.npz").read_bytes() == (tmp_path / "memory.npz").read_bytes()
    assert not (tmp_path / "run" / SPILL_DIR).exists()


def test_npz_row_blocks_read_the_saved_array_and_tracking_rmse_agrees_bit_for_bit(tmp_path):
    """NpzLog.row_blocks gives the saved array block by block; tracking_rmse read that way
    equals the in-memory computation exactly."""
    from testbed.log import NpzLog
    from testbed.runner import tracking_rmse

    rng = np.random.default_rng(5)
    arrays = {"truth/pos": rng.standard_normal((1001, 7, 3)), "reference/pos": rng.standard_normal((1001, 7, 3))}
    save_npz(tmp_path / "log.npz", arrays)
    with NpzLog(tmp_path / "log.npz") as log:
        blocks = list(log.row_blocks("truth/pos", rows=100))
        assert [len(b) for b in blocks] == [100] * 10 + [1]
        np.testing.assert_array_equal(np.concatenate(blocks), arrays["truth/pos"])
        assert tracking_rmse(log) == tracking_rmse(arrays)
