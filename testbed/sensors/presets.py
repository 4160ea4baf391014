"""Named error presets of the sensor streams (the `preset = "..."` key of each [sensors.NAME] table).

Every preset is a flat table of SI values. A preset only fills the error keys a scenario leaves
out; the resolved scenario (scenario.toml of a run) writes every value out, so a run never
depends on this file to be reread. Units: m, s, rad, m/s^2, rad/s; noise densities per sqrt(Hz)
(= per sqrt(s^-1)), random-walk densities per sqrt(s).
"""
from __future__ import annotations

import math

G0 = 9.80665  # m/s^2, standard gravity (to convert the datasheets' g, mg, micro-g)
UG = 1e-6 * G0  # m/s^2 per micro-g
DEG = math.pi / 180.0
DPH = DEG / 3600.0  # rad/s per deg/h
ARW_DEG_SQRT_H = DEG / 60.0  # rad/s/sqrt(Hz) per deg/sqrt(h): 1 sqrt(h) = 60 sqrt(s)

# ------------------------------------------------------------------------------------- IMU
# Keys of one instrument (accel or gyro), per axis, SI:
#   noise_density   white noise density N (m/s^2/sqrt(Hz) or rad/s/sqrt(Hz)); sample sigma N/sqrt(dt)
#   bias            constant bias, the same on every axis and vehicle (m/s^2 or rad/s)
#   bias_sigma      turn-on bias 1 sigma, drawn per vehicle (own child stream) and axis at start
#   bias_walk       bias random-walk density K (unit/s/sqrt(Hz) = unit/sqrt(s)); eq. 2/4 eta_u
#   gm_sigma, gm_tau  first-order Gauss-Markov bias: steady-state 1 sigma and time constant (s)
#   scale_sigma     scale-factor error 1 sigma (dimensionless), diagonal of K_g / K_a (eqs. 1, 3)
#   misalign_sigma  axis misalignment / cross-axis 1 sigma (rad), off-diagonal of K_g / K_a
_ZERO_INSTR = dict(noise_density=0.0, bias=0.0, bias_sigma=0.0, bias_walk=0.0, gm_sigma=0.0, gm_tau=0.0, scale_sigma=0.0, misalign_sigma=0.0)

# Rotor vibration ([sensors.imu.vibration], testbed.sensors.vibration), for the airframe of
# models/quadrotor.xml (DJI M300 class, 21-inch propellers, hover thrust 16.922 N per rotor):
#   thrust_coefficient  k = C_T rho D^4 = 0.1 x 1.225 kg/m^3 x (0.5334 m)^4 = 9.92e-3 N s^2, with
#                       C_T = 0.1 assumed (typical static thrust coefficient of fixed-pitch propellers):
#                       hover at f = sqrt(16.922 / k) = 41.3 rev/s (2480 rpm).
#   accel_xy, accel_z   harmonics 1 (imbalance) and 2 (blade passing of a two-blade propeller), one
#                       amplitude c for all four (assumed: nothing measured favours one), per N of thrust.
#   c, the stated rule: in a hover sampled at 200 Hz, each axis's vibration (four rotors of random phase,
#   through the anti-alias filter) has a per-sample RMS of VIBRATION_RATIO times the preset's static
#   white-noise sigma N sqrt(200 Hz). VIBRATION_RATIO = sqrt(7 x 17) = 10.9, the geometric mean of the
#   in-flight/static ratios (7 to 17) measured on a public recording of three quadrotors (docs/sensors.md).
#   Per axis: RMS^2 = 4 rotors x sum_h (c T |H(h f)|)^2 / 2 (the rotor-plane vector gives cos and sin).
# The vibration is off in `ideal` and in `paper004` (the paper's simulation has none).
HOVER_THRUST = 16.922  # N per rotor, docs/models.md
THRUST_COEFFICIENT = 0.1 * 1.225 * 0.5334**4  # N s^2 (T = k f^2, f in rev/s)
VIBRATION_RATIO = math.sqrt(7.0 * 17.0)


def _butterworth2(f: float, cutoff: float) -> float:
    """|H(f)| of a second-order Butterworth low-pass with -3 dB frequency cutoff (Hz)."""
    return 1.0 / math.sqrt(1.0 + (f / cutoff) ** 4)


def _vibration(noise_density: float, cutoff_ratio: float, rate: float = 200.0) -> dict:
    """The vibration table of a hardware preset by the rule above (accel noise density m/s^2/sqrt(Hz))."""
    f = math.sqrt(HOVER_THRUST / THRUST_COEFFICIENT)
    gain2 = sum(_butterworth2(h * f, cutoff_ratio * rate) ** 2 for h in (1, 2))
    c = VIBRATION_RATIO * noise_density * math.sqrt(rate) / (HOVER_THRUST * math.sqrt(2.0 * gain2))
    return dict(enabled=True, thrust_coefficient=THRUST_COEFFICIENT, accel_xy=(c, c), accel_z=(c, c),
                cutoff_ratio=cutoff_ratio)


_NO_VIBRATION = dict(enabled=False, thrust_coefficient=THRUST_COEFFICIENT, accel_xy=(0.0, 0.0), accel_z=(0.0, 0.0),
                     cutoff_ratio=0.4)

IMU_PRESETS: dict[str, dict[str, dict]] = {
    "ideal": {"accel": dict(_ZERO_INSTR), "gyro": dict(_ZERO_INSTR), "vibration": dict(_NO_VIBRATION)},
    # Seed 004, section 4: accel constant bias 250 micro-g, accel random noise "50 micro-g/sqrt(h)",
    # gyro constant drift 0.1 deg/h, gyro white noise 0.08 deg/sqrt(h). The accel noise unit
    # micro-g/sqrt(h) is not a noise-density unit; read as 50 micro-g/sqrt(Hz) (a navigation-grade
    # accelerometer; the literal /60 reading would give 0.8 micro-g/sqrt(Hz), implausibly good).
    # The gyro 0.08 deg/sqrt(h) is an angle random walk: 0.08/60 deg/s/sqrt(Hz).
    # Biases are constant in time (eq. 2/4 with eta_u = 0, "b_a constant in the paper's run"), and
    # the paper's 250 micro-g / 0.1 deg/h are their 1 sigma: each vehicle and axis draws its own
    # turn-on bias from N(0, sigma^2), the prior the filter assumes. (One fixed value on every
    # vehicle would cancel in the relative problem and flatter every filter.)
    "paper004": {
        "accel": {**_ZERO_INSTR, "noise_density": 50.0 * UG, "bias_sigma": 250.0 * UG},
        "gyro": {**_ZERO_INSTR, "noise_density": 0.08 * ARW_DEG_SQRT_H, "bias_sigma": 0.1 * DPH},
        "vibration": dict(_NO_VIBRATION),
    },
    # Bosch BMI088 (data sheet BST-BMI088-DS001, Table 1 "accelerometer" / Table 2 "gyroscope"),
    # typical values, each datasheet +/- tolerance taken as 1 sigma:
    #   accel output noise density 175 micro-g/sqrt(Hz) (normal mode); zero-g offset +/-20 mg;
    #   sensitivity tolerance +/-0.5 %... taken as 0.5 %; cross-axis sensitivity 0.5 %;
    #   gyro output noise density 0.014 deg/s/sqrt(Hz); zero-rate offset +/-1 deg/s;
    #   sensitivity tolerance +/-1 %; cross-axis sensitivity +/-1 %.
    # Bias instability is not in the data sheet: assumed Gauss-Markov, tau 100 s, with sigma
    # 0.1 mg (accel) and 5 deg/h (gyro), typical of this class of MEMS (Allan-deviation floors).
    # Anti-alias filter: accelerometer bandwidth in normal mode 80 Hz at 200 Hz output data rate
    # (40 Hz at 100 Hz): cutoff_ratio 0.4.
    "bmi088": {
        "accel": dict(noise_density=175.0 * UG, bias=0.0, bias_sigma=20e-3 * G0, bias_walk=0.0,
                      gm_sigma=0.1e-3 * G0, gm_tau=100.0, scale_sigma=0.005, misalign_sigma=0.005),
        "gyro": dict(noise_density=0.014 * DEG, bias=0.0, bias_sigma=1.0 * DEG, bias_walk=0.0,
                     gm_sigma=5.0 * DPH, gm_tau=100.0, scale_sigma=0.01, misalign_sigma=0.01),
        "vibration": _vibration(175.0 * UG, 0.4),
    },
    # InvenSense MPU-9250 (product specification PS-MPU-9250A-01 rev 1.1, tables 1 and 2):
    #   gyro rate noise spectral density 0.01 deg/s/sqrt(Hz); initial zero-rate offset tolerance
    #   +/-5 deg/s; sensitivity scale factor tolerance +/-3 %; cross-axis sensitivity +/-2 %;
    #   accel noise power spectral density 300 micro-g/sqrt(Hz); zero-g initial calibration
    #   tolerance +/-60 mg (x, y; +/-80 mg z, 60 mg used); initial sensitivity tolerance +/-3 %;
    #   cross-axis sensitivity +/-2 %.
    # Bias instability not in the data sheet: assumed Gauss-Markov, tau 100 s, 0.2 mg and
    # 10 deg/h. Anti-alias filter: the digital low-pass A_DLPF_CFG = 2 (92 Hz) at a 200 Hz
    # sample rate, an assumed flight-controller setting: cutoff_ratio 0.46.
    "mpu9250": {
        "accel": dict(noise_density=300.0 * UG, bias=0.0, bias_sigma=60e-3 * G0, bias_walk=0.0,
                      gm_sigma=0.2e-3 * G0, gm_tau=100.0, scale_sigma=0.03, misalign_sigma=0.02),
        "gyro": dict(noise_density=0.01 * DEG, bias=0.0, bias_sigma=5.0 * DEG, bias_walk=0.0,
                     gm_sigma=10.0 * DPH, gm_tau=100.0, scale_sigma=0.03, misalign_sigma=0.02),
        "vibration": _vibration(300.0 * UG, 0.46),
    },
}

# ------------------------------------------------------------------------------------- UWB
# Clock and antenna-delay keys (testbed.sensors.uwb has the equations):
#   mode                "scale" (range x (1 + mean of the two clock offsets): the first-order
#                       double-sided model, kept as the default of the SPEC presets), "ss-twr"
#                       or "ds-twr" (the exact timestamp arithmetic of both two-way schemes)
#   clock_ppm           1 sigma of each device's crystal frequency offset (ppm)
#   reply_time          responder's reply delay of SS-TWR (s, on its own clock); DS-TWR (the
#                       asymmetric formula) does not depend on it
#   antenna_delay_sigma 1 sigma of each device's antenna-delay residual, as range (m): a range
#                       between devices A and B carries b_A + b_B
DW1000_REPLY_TIME = 330e-6  # s: the DW1000 SS-TWR example responder's delay, 330 UWB microseconds (~0.34 ms)
UWB_PRESETS: dict[str, dict[str, float | str]] = {
    "ideal": dict(noise=0.0, loss_prob=0.0, clock_ppm=0.0, mode="scale", reply_time=DW1000_REPLY_TIME,
                  antenna_delay_sigma=0.0, link_bias_sigma=0.0, nlos="ignore",
                  nlos_bias_mean=0.0, nlos_bias_per_m=0.0, nlos_noise_factor=1.0, outlier_prob=0.0, outlier_sigma=0.0),
    # Seed 001 (SPEC defaults for its lost Table 2): 0.10 m white noise, 20 ppm crystal scale
    # factor; the paper has no NLOS: the physics still flags blocked links, which get the DW1000
    # NLOS model below.
    "paper001": dict(noise=0.10, loss_prob=0.0, clock_ppm=20.0, mode="scale", reply_time=DW1000_REPLY_TIME,
                     antenna_delay_sigma=0.0, link_bias_sigma=0.0, nlos="bias",
                     nlos_bias_mean=0.3, nlos_bias_per_m=1.0, nlos_noise_factor=3.0, outlier_prob=0.0, outlier_sigma=0.0),
    # A Decawave DW1000-class two-way ranging radio: +/-10 cm LOS accuracy (DW1000 data sheet),
    # 38.4 MHz reference crystal of the +/-20 ppm class (taken as 1 sigma, untrimmed), asymmetric
    # double-sided TWR (Decawave APS013, the scheme its application notes recommend against the
    # clock error of SS-TWR, APS011), antenna delay calibrated per unit (DW1000 user manual,
    # "antenna delay calibration"; APS014) to a residual of 3.5 cm per device (the 5 cm per link
    # of this preset's earlier per-link model split over the two ends, 5 / sqrt(2)), 2 % packet
    # loss; NLOS: exponential excess delay with mean 0.3 m plus 1 m per m of blocking material
    # ((sqrt(eps_r) - 1) ~ 1 for concrete/brick), 3x noise; 1 % gross outliers of 3 m
    # (multipath lock-on to a late path).
    "dw1000": dict(noise=0.10, loss_prob=0.02, clock_ppm=20.0, mode="ds-twr", reply_time=DW1000_REPLY_TIME,
                   antenna_delay_sigma=0.035, link_bias_sigma=0.0, nlos="bias",
                   nlos_bias_mean=0.3, nlos_bias_per_m=1.0, nlos_noise_factor=3.0, outlier_prob=0.01, outlier_sigma=3.0),
}

# ----------------------------------------------------------------------------------- phase
PHASE_PRESETS: dict[str, dict[str, float]] = {
    "ideal": dict(phase_noise=0.0, coarse_noise=0.0, slip_prob=0.0, master_pos_noise=0.0, master_vel_noise=0.0),
    # Seed 003: range noise 0.15 m (3 sigma) -> 0.05 m 1 sigma on every wrapped phase sample (in
    # range terms); the range rate noise 0.3 m/s (3 sigma) follows from eq. 7 with the default
    # T = 20 ms and N + 1 = 35 periods: sqrt(2) 0.05 / 0.7 = 0.101 m/s. Coarse range for the
    # ambiguity: 0.05 m (code ranging on the same radios; keeps false slip alarms < 1e-11/check).
    # Masters' antenna positions known exactly, as in the paper.
    "paper003": dict(phase_noise=0.05, coarse_noise=0.05, slip_prob=0.0, master_pos_noise=0.0, master_vel_noise=0.0),
}

# ------------------------------------------------------------------------------------ GNSS
GNSS_PRESETS: dict[str, dict[str, float]] = {
    "ideal": dict(noise_h=0.0, noise_v=0.0, bias_h=0.0, bias_v=0.0, bias_tau=0.0),
    # Seed 001 (SPEC): standalone GNSS 1.5 m horizontal / 3.0 m vertical 1 sigma, Gaussian white.
    "spp": dict(noise_h=1.5, noise_v=3.0, bias_h=0.0, bias_v=0.0, bias_tau=0.0),
    # The same totals, but most of it a slowly varying bias (atmosphere, orbits): white 0.5/1.0 m,
    # Gauss-Markov 1.41/2.83 m with tau 300 s (total 1.5/3.0 m).
    "spp-correlated": dict(noise_h=0.5, noise_v=1.0, bias_h=1.414, bias_v=2.828, bias_tau=300.0),
    # Seed 001 (SPEC): RTK 0.02 m horizontal / 0.03 m vertical.
    "rtk": dict(noise_h=0.02, noise_v=0.03, bias_h=0.0, bias_v=0.0, bias_tau=0.0),
}

# ---------------------------------------------------------------------------------- camera
CAMERA_PRESETS: dict[str, dict[str, float]] = {
    "ideal": dict(sigma=0.0, d=1.0, glint_prob=0.0, glint_factor=1.0),
    # Seed 004: vision noise 3500 micro-rad; glint contamination rate 0.1 with 5x std. d of eq. 8 is
    # not given; d = 1 (Crassidis' VisNav papers).
    "paper004": dict(sigma=3500e-6, d=1.0, glint_prob=0.1, glint_factor=5.0),
    "gaussian": dict(sigma=3500e-6, d=1.0, glint_prob=0.0, glint_factor=1.0),
}
