"""What the ROS bags of a dataset share (docs/replay.md, "ROS bags"): the optional rosbags package,
the message types with the testbed's own link message registered, and ROS time stamps.

rosbags is the `bags` extra, imported only here and only when a bag is read or written, so the
rest of the testbed runs without it; without it, a bag is one line naming the extra (exit 2).
"""
from __future__ import annotations

import importlib

from testbed.errors import UsageError

INSTALL = "ROS bags need the rosbags package: install the bags extra: pip install '.[bags]'"

#: One measured link, a row of links.csv; the topic's stream (uwb, phase, range-rate) says what
#: `value` is. Its definition is stored in every bag written, so any ROS 2 tool can decode it.
LINK_TYPE = "testbed_msgs/msg/Link"
LINK_MSG = """\
# One measured link between two sites (BODY/SITE) or a site and an anchor: a row of links.csv.
std_msgs/Header header  # stamp: the time of validity; frame_id: unused
string src              # the site or anchor that ranged
string dst              # the site or anchor ranged to
float64 value           # range m (streams uwb, phase) or range rate m/s (stream range-rate)
float64 sigma           # its declared 1-sigma, unit of value; NaN when none is declared
"""


def rosbags(module: str):
    """The rosbags submodule `module` (e.g. "highlevel"); UsageError naming the extra without it."""
    try:
        return importlib.import_module(f"rosbags.{module}")  # lazy: the optional `bags` extra
    except ImportError:
        raise UsageError(INSTALL) from None


def typestore(ros1: bool = False):
    """The message types of ROS 2 Humble (ROS 1 Noetic when ros1) with LINK_TYPE registered."""
    ts = rosbags("typesys")
    store = ts.get_typestore(ts.Stores.ROS1_NOETIC if ros1 else ts.Stores.ROS2_HUMBLE)
    store.register(ts.get_types_from_msg(LINK_MSG, LINK_TYPE))
    return store


def nanoseconds(t: float) -> int:
    """A time in s as integer ns, the resolution of a ROS stamp."""
    return round(t * 1e9)


def seconds(ns: int) -> float:
    """Integer ns as s (the float nearest to ns / 1e9)."""
    return ns / 10**9
