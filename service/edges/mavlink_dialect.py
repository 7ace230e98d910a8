"""The one place pymavlink is imported: MAVLink 2 and the ardupilotmega dialect, always.

pymavlink reads ``MAVLINK20`` and ``MAVLINK_DIALECT`` from the environment when ``mavutil`` is
first imported and silently falls back to MAVLink 1 (no signing, truncated extensions) or to
the ``all`` dialect without them. Every module that needs pymavlink calls ``mavutil()`` or
``dialect()`` here instead of importing it, so the environment is always set first.
"""

from __future__ import annotations

import importlib
import os
from types import ModuleType

from service.core.errors import LinkError

DIALECT = "ardupilotmega"
"""ArduPilot's dialect: common.xml plus WIND, the message ArduPilot sends its flow estimate in."""

_DIALECT_MODULE = f"pymavlink.dialects.v20.{DIALECT}"


def mavutil() -> ModuleType:
    """``pymavlink.mavutil`` set up for MAVLink 2 and the ardupilotmega dialect."""
    os.environ["MAVLINK20"] = "1"
    os.environ["MAVLINK_DIALECT"] = DIALECT
    module = importlib.import_module("pymavlink.mavutil")
    # Someone imported mavutil before us (without the environment): switch its global dialect.
    if getattr(module.mavlink, "__name__", "") != _DIALECT_MODULE:
        module.set_dialect(DIALECT)
    if module.mavlink.WIRE_PROTOCOL_VERSION != "2.0":
        raise LinkError(f"pymavlink loaded MAVLink {module.mavlink.WIRE_PROTOCOL_VERSION}, expected 2.0")
    return module


def dialect() -> ModuleType:
    """The generated ardupilotmega MAVLink 2 module: message classes, enums and constants."""
    module: ModuleType = mavutil().mavlink
    return module
