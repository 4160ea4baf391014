"""Coverage of the per-run ANEES interval (testbed.scoring.metrics.sample_size, anees_keys) on simulated
NEES series of an exactly consistent estimator: the table of docs/consistency.md, "Decidable from one run".

    .venv/bin/python -m tests.interval_coverage [--runs R] [--steps T ...]

Every generator returns NEES (R, T) of 3-D errors e_t with their exact covariance P_t:
- ar1_nees: a stationary AR(1) error (P = I) whose NEES has integrated time tau;
- random_walk_nees: a random walk, P_t = t I (correlated over the whole run, no stationary tau);
- line_fit_nees: the filter of a constant-velocity line fitted to all the noisy positions so far
  (prior from P0, no process noise), the exact model of its truth: its error is correlated over
  the run, as a phase filter's at q -> 0 (docs/papers.md, "The body's conservatism ...").

Per case the table gives the rate at which the run is decidable (span >= MIN_SPAN), the coverage
of the decided intervals, and P(decided and outside), which a consistent estimator must keep at
1 - level, for the threshold in force and the candidates around it. MIN_SPAN was derived on the
AR(1) rows only: the smallest candidate whose P(decided and outside) stays within 1 - level plus
two binomial standard errors on every AR(1) row; the random walk and the line fit check it.
"""
from __future__ import annotations

import argparse

import numpy as np
from scipy.signal import lfilter

from testbed.scoring.metrics import MIN_SPAN, anees_interval, sample_size

DOF, LEVEL = 3, 0.99
#: tau / T of the AR(1) rows, from T/1000 to T/2
FRACTIONS = (1 / 1000, 1 / 300, 1 / 100, 1 / 50, 1 / 30, 1 / 20, 1 / 15, 1 / 10, 1 / 7, 1 / 5, 1 / 3, 1 / 2)
CANDIDATES = (10.0, 15.0, 20.0, 25.0, 30.0)


def ar1_nees(tau: float, runs: int, steps: int, rng: np.random.Generator) -> np.ndarray:
    """(runs, steps) NEES of a stationary 3-D AR(1) error e_t = a e_{t-1} + w_t, P = I, whose NEES
    has integrated time tau = (1 + a^2) / (1 - a^2) (tau >= 1)."""
    a = np.sqrt((tau - 1) / (tau + 1))
    w = rng.standard_normal((runs, steps, DOF)) * np.sqrt(1 - a * a)
    w[:, 0] = rng.standard_normal((runs, DOF))  # e_0 ~ N(0, I): stationary from the start
    return (lfilter([1.0], [1.0, -a], w, axis=1) ** 2).sum(-1)


def random_walk_nees(runs: int, steps: int, rng: np.random.Generator) -> np.ndarray:
    """(runs, steps) NEES |W_t|^2 / t of a 3-D unit random walk W_t, t = 1 .. steps."""
    w = rng.standard_normal((runs, steps, DOF)).cumsum(1)
    return (w**2).sum(-1) / np.arange(1, steps + 1)


def line_fit_nees(runs: int, steps: int, rng: np.random.Generator, dt: float = 0.1, sigma: float = 0.05,
                  sigma_p: float = 0.5, sigma_v: float = 0.1) -> np.ndarray:
    """(runs, steps) NEES of the position of a constant-velocity line fitted (Kalman filter, no
    process noise) to positions measured every dt s with noise sigma m, prior N(truth, diag(sigma_p^2,
    sigma_v^2)) on the position (m) and velocity (m/s) at t = 0, in each of 3 axes."""
    t = np.arange(1, steps + 1) * dt
    h = np.stack([np.ones(steps), t], 1)  # (T, 2): position at t from (p0, v0)
    info0 = np.diag([sigma_p**-2, sigma_v**-2])
    cov = np.linalg.inv(info0 + np.cumsum(h[:, :, None] * h[:, None, :], 0) / sigma**2)  # (T, 2, 2)
    p = np.einsum("ti,tij,tj->t", h, cov, h)  # (T,) the position's variance
    out = np.zeros((runs, steps))
    for _ in range(DOF):
        prior = rng.standard_normal((runs, 2)) * [sigma_p, sigma_v]  # prior error
        noise = rng.standard_normal((runs, steps)) * sigma
        b = (prior @ info0)[:, None, :] + np.cumsum(h[None] * noise[:, :, None], 1) / sigma**2  # (R, T, 2)
        e = np.einsum("tij,rtj,ti->rt", cov, b, h)  # (R, T) position error of the estimate
        out += e**2 / p
    return out


def judged(nees: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(span, inside) (R,) of each run: the correlation times its series spans and whether its ANEES
    lies in its interval (anees_interval over sample_size's n_eff and nu, taken whatever the span)."""
    span, inside = np.zeros(len(nees)), np.zeros(len(nees), bool)
    for i, x in enumerate(nees):
        s = sample_size(x)
        lo, hi = anees_interval(DOF, s.n_eff, LEVEL, s.nu)
        span[i], inside[i] = s.span, lo <= x.mean() <= hi
    return span, inside


def table(steps: int, runs: int, seed: int = 0) -> list[list]:
    """Rows [case, steps, tau/T, decided share, coverage of the decided, P(decided and outside) at
    MIN_SPAN, then at each of CANDIDATES]."""
    rng = np.random.default_rng(seed + steps)
    cases = [(f"AR(1) T/tau = {1 / f:g}", lambda f=f: ar1_nees(max(1.0, f * steps), runs, steps, rng)) for f in FRACTIONS]
    cases += [("random walk", lambda: random_walk_nees(runs, steps, rng)),
              ("line fit", lambda: line_fit_nees(runs, steps, rng))]
    rows = []
    for name, make in cases:
        span, inside = judged(make())
        dec = span >= MIN_SPAN
        rows.append([name, steps, float(dec.mean()), float(inside[dec].mean()) if dec.any() else float("nan"),
                     float(np.mean(dec & ~inside)), *(float(np.mean((span >= c) & ~inside)) for c in CANDIDATES)])
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=4000)
    ap.add_argument("--steps", type=int, nargs="+", default=[500, 2000])
    a = ap.parse_args(argv)
    bound = (1 - LEVEL) + 2 * np.sqrt(LEVEL * (1 - LEVEL) / a.runs)
    print(f"{a.runs} runs a case, level {LEVEL}, MIN_SPAN {MIN_SPAN:g}; P(decided and outside) bound {bound:.4f}")
    print("| case | T | decided | coverage of the decided | P(decided, outside) | "
          + " | ".join(f"at {c:g}" for c in CANDIDATES) + " |")
    print("|---|---|---|---|---|" + "---|" * len(CANDIDATES))
    for steps in a.steps:
        for name, t, dec, cov, out, *cand in table(steps, a.runs):
            print(f"| {name} | {t} | {dec:.3f} | {cov:.4f} | {out:.4f} | " + " | ".join(f"{c:.4f}" for c in cand) + " |",
                  flush=True)


if __name__ == "__main__":
    main()
