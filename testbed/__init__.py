"""MuJoCo physics-in-the-loop testbed for cooperative navigation of UAV swarms."""
import os

# Headless rendering by default; must be set before mujoco is imported anywhere.
os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"
