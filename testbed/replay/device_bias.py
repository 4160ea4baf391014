"""Device biases from link biases (docs/calibration.md, cal. 9): the part of each link's bias that
its two radios carry into every link they end (an antenna delay), and the link's remainder.

Given the calibrated biases b_l (m) of L links, each between two devices (sites or anchors), the
device biases beta (D,) m solve, by least squares with the minimum norm,

    b_l = beta_src(l) + beta_dst(l) + r_l,   min sum_l r_l^2,   then min |beta|          (cal. 9)

The minimum norm fixes what the links cannot tell apart: with links only between two groups
(anchors and tags), adding c to every anchor and -c to every tag changes no sum; a device that
ends one link only shares that link's bias with its other end. Each calibrated link keeps its
total: its row's bias is the remainder r_l, and on replay the device rows and the link row add up
to b_l again (testbed.replay.calibration). What the device rows add is a prediction for a link the
segment did not calibrate: beta_src + beta_dst. The rule that keeps them: they must predict the
calibrated links better than no device model does, by leave-one-link-out cross-validation,

    sum_l (b_l - bhat_l)^2 < sum_l b_l^2,   bhat_l from the fit without link l            (cal. 9b)

(a device that ends link l alone predicts 0 for its part). Never imports mujoco.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["DeviceSplit", "device_split", "incidence"]


@dataclass(frozen=True, slots=True)
class DeviceSplit:
    """devices {name: beta m}; remainder (L,) m, r_l of each link in the order given; rms_bias m,
    the links' biases' rms about zero; rms_loo m, the leave-one-link-out prediction error's rms;
    kept: cal. 9b holds (rms_loo < rms_bias)."""

    devices: dict[str, float]
    remainder: np.ndarray
    rms_bias: float
    rms_loo: float
    kept: bool


def incidence(ends: list[tuple[str, str]]) -> tuple[dict[str, int], np.ndarray]:
    """The devices of links ends [(src, dst)] (L,): {name: column} in sorted order, and the
    incidence matrix A (L, D), 1 in the columns of each link's two devices (cal. 9, 10)."""
    col = {n: j for j, n in enumerate(sorted({n for pair in ends for n in pair}))}
    A = np.zeros((len(ends), len(col)))
    for i, (a, b) in enumerate(ends):
        A[i, col[a]] = A[i, col[b]] = 1.0
    return col, A


def _fit(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The minimum-norm least-squares beta of A beta = b (cal. 9)."""
    return np.linalg.lstsq(A, b, rcond=None)[0]


def device_split(ends: list[tuple[str, str]], bias: np.ndarray) -> DeviceSplit:
    """Split the biases bias (L,) m of the links ends [(src, dst)] into device biases and link
    remainders (cal. 9), and test the device model by leave-one-link-out (cal. 9b)."""
    bias = np.asarray(bias, float)
    col, A = incidence(ends)
    beta = _fit(A, bias)
    pred = np.empty_like(bias)
    for i in range(len(ends)):
        keep = np.arange(len(ends)) != i
        # eq. cal. 9b: link i predicted by the devices fitted on the other links
        pred[i] = A[i] @ _fit(A[keep], bias[keep])
    rms_bias = float(np.sqrt(np.mean(bias ** 2))) if bias.size else 0.0
    rms_loo = float(np.sqrt(np.mean((bias - pred) ** 2))) if bias.size else 0.0
    return DeviceSplit({n: float(beta[j]) for n, j in col.items()}, bias - A @ beta, rms_bias, rms_loo,
                       bool(bias.size >= 2 and rms_loo < rms_bias))
