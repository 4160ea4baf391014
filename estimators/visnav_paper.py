"""The seed 004 paper's sensor figures (section 3.1) in SI units: plain Python floats, no numpy or
scipy, so that configuration code can use them as defaults without loading the estimators."""
import math

G0 = 9.80665                        # m/s^2 per g
DEG = math.pi / 180.0               # rad per degree
HOUR = 3600.0                       # s per hour

PAPER_ACCEL_BIAS = 250e-6 * G0                    # 250 micro-g -> m/s^2
# printed "50 micro-g/sqrt(h)", not a noise-density unit: read as 50 micro-g/sqrt(Hz), as the
# paper004 IMU preset and the pipeline do (docs/sensors.md; the literal reading is 0.8 ug/sqrt(Hz))
PAPER_ACCEL_NOISE = 50e-6 * G0                    # 50 micro-g/sqrt(Hz) -> m/s/sqrt(s)
PAPER_GYRO_BIAS = 0.1 * DEG / HOUR                # 0.1 deg/h -> rad/s
PAPER_GYRO_NOISE = 0.08 * DEG / math.sqrt(HOUR)   # 0.08 deg/sqrt(h) -> rad/sqrt(s)
PAPER_VISION_SIGMA = 3500e-6                      # rad
PAPER_FOCAL_LENGTH = 1.0                          # m
PAPER_GLINT_RATE = 0.1                            # contamination probability
PAPER_GLINT_SCALE = 5.0                           # std of the contaminating component / nominal
