"""MuJoCo physics-in-the-loop testbed for cooperative navigation of UAV swarms."""
import os

# Headless rendering by default; must be set before mujoco is imported anywhere.
os.environ.setdefault("MUJOCO_GL", "egl")
# Small dense linear algebra (90 x 90 filter solves) is 10x slower with threaded BLAS on a busy
# machine; parallelism comes from worker processes (testbed sweep) instead.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

__version__ = "0.1.0"
