"""MuJoCo physics-in-the-loop testbed for cooperative navigation of UAV swarms.

Importing it has no side effect; the command line sets its environment (testbed.environment).
"""

__version__ = "0.1.0"
