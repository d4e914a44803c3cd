"""The error hierarchy every driver raises.

DeviceError
├── DeviceTimeout      nothing (or not enough) arrived in time
├── ConnectionLost     the peer closed or reset the connection / could not be reached
├── ProtocolError      bytes that do not parse, or an answer that does not fit the request
├── ProgramError       a controller program that cannot be written (drivers/*/program.py): its language refuses it
└── DeviceFault        the device itself reports a fault, with its own code
    ├── MotionRefused  a motion target rejected before anything was sent (limits, cell box)
    └── TargetNotVisible  the tracker cannot see the reflector from where it stands (no lock, beam broken)
"""

from __future__ import annotations


class DeviceError(Exception):
    """Base of every driver error. `device` names the device, e.g. 'tracker 127.0.0.1:700'."""

    def __init__(self, message: str, *, device: str = "") -> None:
        self.device = device
        super().__init__(f"{device}: {message}" if device else message)


class DeviceTimeout(DeviceError):
    """A read or an answer did not arrive within its timeout."""


class ConnectionLost(DeviceError):
    """The connection could not be opened, or the peer closed or reset it."""


class ProtocolError(DeviceError):
    """Malformed bytes, an unknown enum value, a size out of range, an unexpected answer."""


class DeviceFault(DeviceError):
    """The device reports a fault. `code` is the device's own code (e.g. an emScon ES_ResultStatus)."""

    def __init__(self, message: str, *, code: int | str | None = None, device: str = "") -> None:
        self.code = code
        super().__init__(f"{message} (code {code})" if code is not None else message, device=device)


class MotionRefused(DeviceFault):
    """A motion target outside the joint limits or the cell box: refused before anything was sent."""


class TargetNotVisible(DeviceFault):
    """The tracker cannot measure the reflector from its station: not found, not locked, or beam broken."""


class ProgramError(DeviceError):
    """A controller program that cannot be written (drivers/*/program.py): a name or a target the controller's
    language refuses; the message says why."""
