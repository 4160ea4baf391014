"""The user-facing errors of the testbed: each is one line on stderr and exit code 2 (1 for a
plugin estimator that failed during a run).

Raised anywhere below the command line, caught only in `testbed.cli.main`. A message names the
file, the dotted key and the offending value where there is one; it never needs a traceback.
"""
from __future__ import annotations


class TestbedError(Exception):
    """A mistake the user can fix (exit code 2): one line, no traceback."""

    __test__ = False  # not a pytest test class despite the name
    exit_code = 2


class UsageError(TestbedError):
    """A bad command-line argument."""


class ConfigError(TestbedError):
    """A bad scenario or configuration value: names the file, the dotted key and the value."""


class FieldError(ConfigError):
    """One configuration key with a bad value.

    file: the file it came from ('' when built in code); key: dotted path (`world.anchors[2]`);
    value: the offending value; reason: what is wrong with it.
    """

    def __init__(self, file: str, key: str, value: object, reason: str) -> None:
        self.file, self.key, self.value, self.reason = file, key, value, reason
        where = f"{file}: " if file else ""
        super().__init__(f"{where}{key}: {reason}" if key else f"{where}{reason}")


class RunError(TestbedError):
    """A problem with an output location (exists, not ours, not writable)."""


class PluginError(TestbedError):
    """A plugin estimator failed during a run (raised, returned NaN or a wrong shape): exit code 1.

    The message names the estimator, the time and what was wrong; `time` (s, run clock) is the
    time of the measurement it was given when it failed, None when it failed outside the feed
    (constructor, finish, health). A plugin that cannot be loaded or lacks the protocol is a
    UsageError (exit 2), found before anything is simulated.
    """

    exit_code = 1

    def __init__(self, message: str, time: float | None = None) -> None:
        super().__init__(message)
        self.time = time


class EstimatorsFailed(PluginError):
    """Some estimators of a run, replay or sweep failed; the others were scored and the output
    was written anyway, marked incomplete (testbed.plugins.failures): exit code 1."""
