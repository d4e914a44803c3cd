"""Recording and playing back every device call, so that replay is the same engine fed by a recording.

Live: each driver (and the operator and the campaign clock) is wrapped in a `Recorder`, which emits
every call with its arguments and its result (or its error) as a `call` document (engine.RunContext: the
session store, a subscriber, commits it) before handing the result to the engine. Replay: `Player`s stand in
for the devices and return the recorded results in order, after checking that the engine asks exactly what it
asked in the recording; the first call that differs stops the replay with the step and both calls named.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Any

import trackcal.drivers.errors as derr
from trackcal.campaign.engine.documents import CallDoc, CallError
from trackcal.campaign.errors import CampaignError
from trackcal.drivers.interfaces import Environment, TrackerMeasurement, TrackerStatus

if TYPE_CHECKING:  # the engine builds recorders with its run context; engine.py imports this module
    from trackcal.campaign.engine.engine import RunContext  # annotations only: TYPE_CHECKING

TYPES = {cls.__name__: cls for cls in (Environment, TrackerMeasurement, TrackerStatus)}
ERRORS = {
    cls.__name__: cls
    for cls in (
        derr.DeviceError,
        derr.DeviceTimeout,
        derr.ConnectionLost,
        derr.ProtocolError,
        derr.DeviceFault,
        derr.MotionRefused,
        derr.TargetNotVisible,
    )
}


class ReplayDivergence(CampaignError):
    """The engine asked a device for something the recording does not hold at this point."""


class EndOfSegment(Exception):
    """The recorded run ended here (the recorded process stopped or was killed): the replay stops the same way."""


def encode(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and type(value).__name__ in TYPES:
        return {
            "__type__": type(value).__name__,
            **{f.name: encode(getattr(value, f.name)) for f in dataclasses.fields(value)},
        }
    if isinstance(value, (tuple, list)):
        return [encode(v) for v in value]
    if isinstance(value, float | int | str | bool) or value is None:
        return value
    if hasattr(value, "item"):  # numpy scalars
        return value.item()
    raise TypeError(f"cannot record a value of type {type(value).__name__}")


def decode(value: Any) -> Any:
    if isinstance(value, dict) and "__type__" in value:
        cls = TYPES[value["__type__"]]
        return cls(**{k: decode(v) for k, v in value.items() if k != "__type__"})
    if isinstance(value, list):
        return tuple(decode(v) for v in value)
    return value


def encode_error(exc: BaseException) -> CallError:
    return CallError(
        type=type(exc).__name__, message=str(exc), code=getattr(exc, "code", None), device=getattr(exc, "device", "")
    )


def decode_error(err: dict) -> BaseException:
    cls = ERRORS.get(err["type"], derr.DeviceError)
    if issubclass(cls, derr.DeviceFault):
        exc = cls.__new__(cls)
        Exception.__init__(exc, err["message"])
        exc.code, exc.device = err.get("code"), err.get("device", "")
        return exc
    exc = cls.__new__(cls)
    Exception.__init__(exc, err["message"])
    exc.device = err.get("device", "")
    return exc


class Recorder:
    """Wraps a device: every public method call is emitted as a `call` document (result or error), at the step
    and campaign time of the moment it was made."""

    def __init__(self, name: str, target: Any, context: RunContext):
        self._name, self._target, self._context = name, target, context

    def __getattr__(self, op: str):
        fn = getattr(self._target, op)
        if not callable(fn) or op.startswith("_"):
            return fn

        def call(*args):
            step, t = self._context.where()
            record = CallDoc(device=self._name, op=op, args=encode(list(args)))
            try:
                result = fn(*args)
            except derr.DeviceError as exc:
                self._context.emit("call", CallDoc(**record, error=encode_error(exc)), step, t)
                raise
            self._context.emit("call", CallDoc(**record, result=encode(result)), step, t)
            return result

        return call


class Playback:
    """The recorded calls of a session (its `call` events: kind, step, data), handed out device by device in
    order; `context` says the step the engine is at."""

    def __init__(
        self,
        events: Iterable,
        context: Callable[[], tuple[int, float]] = lambda: (-1, 0.0),
        ends_abruptly: bool = False,
    ):
        self.context = context
        self.ends_abruptly = ends_abruptly
        self.calls: dict[str, list] = {}
        for e in events:
            if e.kind == "call":
                self.calls.setdefault(e.data["device"], []).append(e)
        self.cursor = dict.fromkeys(self.calls, 0)

    def device(self, name: str) -> Player:
        return Player(name, self)

    def next(self, device: str, op: str, args: list) -> Any:
        step = self.context()[0]
        calls = self.calls.get(device, [])
        i = self.cursor.get(device, 0)
        asked = f"{device}.{op}{tuple(args)}"
        if i >= len(calls):
            if self.ends_abruptly:
                raise EndOfSegment(f"step {step}: the recorded run stopped before {asked}")
            raise ReplayDivergence(f"step {step}: this run asks {asked}, the recording has no more {device} calls")
        rec = calls[i]
        expected = f"{device}.{rec.data['op']}{tuple(rec.data['args'])}"
        if rec.data["op"] != op or rec.data["args"] != args:
            raise ReplayDivergence(
                f"step {step}: this run asks {asked}, the recording has {expected} (recorded at step {rec.step})"
            )
        self.cursor[device] = i + 1
        if "error" in rec.data:
            raise decode_error(rec.data["error"])
        return decode(rec.data["result"])

    def unused(self) -> dict[str, int]:
        return {d: len(c) - self.cursor[d] for d, c in self.calls.items() if len(c) > self.cursor[d]}


class Player:
    def __init__(self, name: str, playback: Playback):
        self._name, self._playback = name, playback

    def __getattr__(self, op: str):
        if op.startswith("_"):
            raise AttributeError(op)

        def call(*args):
            return self._playback.next(self._name, op, encode(list(args)))

        return call
