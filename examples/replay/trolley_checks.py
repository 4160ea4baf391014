"""Check the trolley's ranges against its truth, on the calibration segment and the scored window apart.

    python examples/replay/trolley_checks.py

No estimator runs here. Every figure compares the recorded ranges (examples/replay/trolley/) with
the ranges that the motion capture pose gives, through trolley.py's frames, lever arms and anchors.
The two parts of the run are the calibration segment (the first CALIBRATION_FRACTION of the UWB
span) and the scored window (the rest). Each link's bias is its mean over the calibration segment.
The range sigma is SIGMA, the one `testbed calibrate` fits on the segment (docs/replay.md). The
checks are those of docs/replay.md, "Why the trolley's estimates are overconfident":
1. a time offset between the truth and the UWB clock;
2. an offset of the truth fixed in the body frame, and a yaw offset;
3. range errors that depend on the azimuth of arrival (an antenna pattern), fitted on the segment
   and used to predict the window;
4. whether the noise is stationary, tested with the pose fit linearised at the truth, and whether
   the three tags' errors move together as one rigid motion.
"""
from __future__ import annotations

import sys

import numpy as np

import trolley as T

SIGMA = 0.0686  # m, the range noise `testbed calibrate` gives on the segment (docs/replay.md)
CLIP = 0.3      # m, the residual beyond which a range counts as an outlier (|residual| > 4 sigma)
DEG = np.degrees


def load() -> dict:
    """Ranges r (N, 8, 3) m at UWB times tu (N,) s, truth tm (M,) s, p (M, 3) m, q (M, 4) wxyz,
    and the segment mask cal (N,). Rows are kept only where the truth brackets them by 0.4 s."""
    tu, r = T.read_uwb(T.RAW / T.UWB_FILE)
    tm, p, q = T.read_mocap(T.RAW / T.MOCAP_FILE)
    tm, tu = np.round(tm - tu[0], 3), np.round(tu - tu[0], 3)
    end = round(T.CALIBRATION_FRACTION * tu[-1], 3)
    keep = (tu >= tm[0] + 0.4) & (tu <= tm[-1] - 0.4)
    return {"tu": tu[keep], "r": r[keep], "tm": tm, "p": p, "q": q, "cal": tu[keep] < end}


def pose_jacobian(tags: np.ndarray, rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ranges (N, 8, 3) m from the anchors to tags (N, 3, 3) m world. J (N, 24, 6): their derivative in
    the body origin (m, world) and in a small rotation phi (rad, world; R -> exp(phi) R), where
    d range / d phi = (R a) x u, with u the unit anchor-to-tag vector and R a the lever arm in world."""
    d = tags[:, None] - T.ANCHORS[None, :, None]
    rng = np.linalg.norm(d, axis=-1)
    u = d / rng[..., None]
    arm = np.einsum("nij,kj->nki", rot, T.TAGS)
    # tf. 1 (docs/replay.md)
    jac = np.concatenate([u, np.cross(arm[:, None], u)], axis=-1)
    return rng, jac.reshape(len(tags), 24, 6)


def fit_at_truth(e: np.ndarray, jac: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per epoch, the Gauss-Newton step at the truth: dx (N, 6) (position m, rotation rad, world)
    from the residuals e (N, 24) m (NaN where missing), and its covariance SIGMA^2 (J^T J)^-1 (N, 6, 6)."""
    ok = np.isfinite(e)
    j0, e0 = jac * ok[..., None], np.where(ok, e, 0.0)
    h = np.einsum("nli,nlj->nij", j0, j0)
    # tf. 2 (docs/replay.md)
    return np.linalg.solve(h, np.einsum("nli,nl->ni", j0, e0)[..., None])[..., 0], SIGMA**2 * np.linalg.inv(h)


def lag_scan(d: dict) -> None:
    """Check 1: the rms residual (clipped at CLIP, each link's own median removed) with the truth
    taken at t + delta."""
    print("1. truth time shift delta s: rms residual m, segment | window")
    for delta in np.arange(-0.10, 0.101, 0.02):
        e = d["r"] - T.true_ranges(d["tu"] + delta, d["tm"], d["p"], d["q"])
        rms = [np.sqrt(np.nanmean(np.clip(e[m] - np.nanmedian(e[m], 0), -CLIP, CLIP) ** 2)) for m in (d["cal"], ~d["cal"])]
        print(f"   {delta:+.2f}: {rms[0]:.4f} | {rms[1]:.4f}")


def row_clock(name: str, t: np.ndarray) -> None:
    """Check 1: a stream's row stamps t (N,) s, as recorded, against a regular clock fitted to the
    row index (the logger's delay, up to a constant): its rms and its largest mean over 5 s."""
    n = np.arange(len(t))
    fit = np.polyfit(n, t, 1)
    delay = t - np.polyval(fit, n)
    block = np.floor((t - t[0]) / 5.0)
    largest = max(abs(delay[block == i].mean()) for i in np.unique(block))
    print(f"1. {name} row stamps against a regular clock of period {fit[0] * 1e3:.4f} ms: rms {delay.std() * 1e3:.1f} ms, "
          f"largest 5-s mean {largest * 1e3:.1f} ms")


def rigid_split(e: np.ndarray, tags: np.ndarray, rot: np.ndarray, rows: np.ndarray) -> tuple[float, float]:
    """Check 4: each tag's horizontal displacement from its own 8 ranges alone (e (N, 8, 3) m at the
    tags (N, 3, 3) m world), split per epoch into a planar rigid motion of the tag triangle (a
    translation and a yaw about the body origin: 3 of the 6 numbers) and the rest. Returns the mean
    energy per dimension m^2 of each over rows (N,) bool; independent per-tag errors give them
    about alike."""
    d = tags[:, None] - T.ANCHORS[None, :, None]
    u = (d / np.linalg.norm(d, axis=-1, keepdims=True))[rows][..., :2]
    a, b = u.transpose(0, 2, 1, 3), e[rows].transpose(0, 2, 1)                  # per tag: (n, 3, 8, 2), (n, 3, 8)
    shift = np.linalg.solve(np.einsum("nkai,nkaj->nkij", a, a), np.einsum("nkai,nka->nki", a, b)[..., None])[..., 0]
    arm = np.einsum("nij,kj->nki", rot[rows], T.TAGS)[..., :2]
    basis = np.zeros((rows.sum(), 6, 3))
    basis[:, 0::2, 0] = basis[:, 1::2, 1] = 1
    basis[:, 0::2, 2], basis[:, 1::2, 2] = -arm[..., 1], arm[..., 0]            # yaw: z x arm
    q = np.linalg.qr(basis)[0]
    y = shift.reshape(-1, 6)
    rigid = np.sum(np.einsum("nij,ni->nj", q, y) ** 2, axis=1)
    return float(rigid.mean() / 3), float((np.sum(y ** 2, axis=1) - rigid).mean() / 3)


def pattern(e: np.ndarray, azimuth: np.ndarray, cal: np.ndarray) -> None:
    """Check 3: per link, e = c0 + c1 cos b + c2 sin b + c3 cos 2b + c4 sin 2b (b the azimuth of
    the anchor in the body frame), fitted on the segment; rms with it against a constant."""
    out = {"constant": np.zeros(2), "pattern": np.zeros(2)}
    for a in range(8):
        for k in range(3):
            ok = np.isfinite(e[:, a, k])
            b = azimuth[ok, a, k]
            x = np.stack([np.ones_like(b), np.cos(b), np.sin(b), np.cos(2 * b), np.sin(2 * b)], axis=-1)
            y, seg = e[ok, a, k], cal[ok]
            c = np.linalg.lstsq(x[seg], y[seg], rcond=None)[0]
            for name, res in (("constant", y - y[seg].mean()), ("pattern", y - x @ c)):
                out[name] += [np.sum(res[seg] ** 2), np.sum(res[~seg] ** 2)]
    n = np.array([np.isfinite(e[cal]).sum(), np.isfinite(e[~cal]).sum()])
    for name, s in out.items():
        print(f"3. per-link {name} fitted on the segment: rms segment {np.sqrt(s[0] / n[0]):.4f}, window {np.sqrt(s[1] / n[1]):.4f} m")


def main() -> int:
    d = load()
    tu, cal = d["tu"], d["cal"]
    lag_scan(d)
    row_clock("UWB", T.read_uwb(T.RAW / T.UWB_FILE)[0])
    row_clock("motion capture", T.read_mocap_rows(T.RAW / T.MOCAP_FILE)[0])
    tags, rot = T.tag_positions(tu, d["tm"], d["p"], d["q"])
    rng, jac = pose_jacobian(tags, rot)
    e = d["r"] - rng
    e = e - np.nanmean(e[cal], axis=0)                        # each link's bias from the segment
    dx, cov = fit_at_truth(e.reshape(len(tu), 24), jac)
    clean = np.isfinite(e).all(axis=(1, 2)) & (np.nanmax(np.abs(e), axis=(1, 2)) < CLIP)
    vel = np.stack([(np.interp(tu + 0.02, d["tm"], d["p"][:, k]) - np.interp(tu - 0.02, d["tm"], d["p"][:, k])) / 0.04
                    for k in range(2)], axis=1)                 # m/s, central differences over 40 ms
    yaw = np.arctan2(rot[:, 1, 0], rot[:, 0, 0])
    c, s = np.cos(yaw), np.sin(yaw)
    to_body = -np.einsum("nji,nakj->naki", rot, (tags[:, None] - T.ANCHORS[None, :, None]) / rng[..., None])
    for m, name in ((cal, "segment"), (~cal, "window")):
        y = dx[m, :2].ravel()
        lag = np.zeros((y.size, 3))                           # mean + tau v
        lag[0::2, 0] = lag[1::2, 1] = 1
        lag[:, 2] = vel[m].ravel()
        arm = np.zeros((y.size, 4))                           # mean + R(yaw) c, c fixed in the body
        arm[0::2, 0] = arm[1::2, 1] = 1
        arm[0::2, 2], arm[0::2, 3], arm[1::2, 2], arm[1::2, 3] = c[m], -s[m], s[m], c[m]
        k_lag, k_arm = (np.linalg.lstsq(x, y, rcond=None)[0] for x in (lag, arm))
        k_mean = np.linalg.lstsq(lag[:, :2], y, rcond=None)[0]
        rms = lambda x, k: np.sqrt(np.mean((y - x @ k) ** 2))  # noqa: E731
        print(f"{name}: horizontal error of the fit at the truth, rms {np.sqrt(np.mean(y ** 2)):.4f} m, "
              f"about its mean {rms(lag[:, :2], k_mean):.4f}")
        print(f"1. error = mean + tau v: tau {k_lag[2]:+.4f} s, rms {rms(lag, k_lag):.4f}")
        print(f"2. error = R(yaw) c: c {k_arm[2:].round(4)} m body, rms {rms(arm, k_arm):.4f}; "
              f"yaw of the ranges against the truth, mean {DEG(dx[m & clean, 5].mean()):+.2f} deg")
        moving = m & (np.linalg.norm(vel, axis=1) > 0.2)
        along = vel[moving] / np.linalg.norm(vel[moving], axis=1, keepdims=True)
        nees = [np.mean(np.einsum("ni,ni->n", dx[moving, :2], w) ** 2 / np.einsum("ni,nij,nj->n", w, cov[moving][:, :2, :2], w))
                for w in (along, along[:, ::-1] * [-1, 1])]
        print(f"1. NEES along the motion {nees[0]:.2f}, across it {nees[1]:.2f} (speed over 0.2 m/s)")
        ahead = np.einsum("ni,ni->n", dx[moving, :2], along) / np.linalg.norm(vel[moving], axis=1)  # s
        block = np.floor(tu[moving] / 5.0)
        lags = [ahead[block == i].mean() for i in np.unique(block) if np.sum(block == i) >= 100]
        print(f"   the lag this implies, mean over 5-s blocks: {min(lags):+.3f} to {max(lags):+.3f} s")
        blocks = [dx[b, 5].mean() for b in (m & clean & (np.floor(tu / 5.0) == i) for i in np.unique(np.floor(tu[m] / 5.0)))
                  if b.sum() >= 100]
        print(f"   in 5-s blocks from {DEG(min(blocks)):+.1f} to {DEG(max(blocks)):+.1f} deg")
        z2 = dx[m, :3] ** 2 / cov[m][:, [0, 1, 2], [0, 1, 2]]
        zc = z2[clean[m]]
        noise = e[m][np.isfinite(e[m])]
        proj = np.einsum("nli,ni->nl", jac[m & clean], dx[m & clean])
        rest = e.reshape(len(tu), 24)[m & clean] - proj
        xs = np.clip(dx[m, 0], -0.1, 0.1) - np.clip(dx[m, 0], -0.1, 0.1).mean()
        ac = [np.dot(xs[:-n], xs[n:]) / np.dot(xs, xs) for n in (10, 100, 300)]  # rows at 100 Hz: 0.1, 1, 3 s
        print(f"4. range residual: rms {np.sqrt(np.mean(noise ** 2)):.4f}, 1.4826 median |residual| {1.4826 * np.median(np.abs(noise)):.4f} m, "
              f"share beyond {CLIP} m {np.mean(np.abs(noise) > CLIP):.4f}")
        nees3 = np.einsum("ni,nij,nj->n", dx[m, :3], np.linalg.inv(cov[m][:, :3, :3]), dx[m, :3]).mean()
        print(f"   position NEES {nees3:.2f}; per axis x, y, z: {z2.mean(0).round(2)}; epochs without an outlier {zc.mean(0).round(2)}; "
              f"median / 0.455 {(np.median(z2, 0) / 0.455).round(2)}")
        print(f"   energy per dof in the pose subspace {np.mean(np.sum(proj ** 2, 1)) / 6:.2e}, "
              f"in the rest {np.mean(np.sum(rest ** 2, 1)) / 18:.2e} m^2 (equal for white noise)")
        rigid, rest3 = rigid_split(e, tags, rot, m & clean)
        print(f"   each tag's displacement from its own ranges, energy per dimension: rigid {rigid:.2e}, "
              f"the rest {rest3:.2e} m^2 (about equal for independent tags)")
        x = e[m & clean] - e[m & clean].mean(axis=0)
        z = (x / x.std(axis=0)).reshape(-1, 24)
        corr = z.T @ z / len(z)
        anchor = np.repeat(np.arange(8), 3)
        same = (anchor[:, None] == anchor[None]) & ~np.eye(24, dtype=bool)
        print(f"   mean correlation of two tags' residuals to one anchor {corr[same].mean():+.3f}")
        print(f"   x error (clipped at 0.1 m) autocorrelation at 0.1, 1, 3 s: {np.round(ac, 2)}")
    drift = np.nanmean(e[~cal], axis=0)
    print(f"4. each link's mean residual, window minus segment: rms {np.sqrt(np.mean(drift ** 2)):.4f}, "
          f"largest {np.abs(drift).max():.4f} m")
    pattern(e, np.arctan2(to_body[..., 1], to_body[..., 0]), cal)
    return 0


if __name__ == "__main__":
    sys.exit(main())
