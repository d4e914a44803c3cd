"""The mock IRC5 controller's state and motion (no sockets): what RobotWare 6 holds that Robot Web Services shows, and
the TrackcalRws module (drivers.abb.program) running in T_ROB1.

- Controller state (RWS "Get Controller State": motoron, motoroff, guardstop, emergencystop, emergencystopreset),
  operating mode AUTO, RAPID execution running / stopped, the module's PERS variables as RAPID text;
- RAPID: while running, main's loop is interpreted: trackcal_move <> trackcal_done starts MoveAbsJ to trackcal_target
  at trackcal_speed % (VelSet) of the axes' maximum speeds; at the end (`fine`) trackcal_done := trackcal_move. A
  RAPID stop brakes on the path (a ramp of BRAKE_S) and keeps the program pointer; resetpp sets it back to main's
  WaitUntil (the move not resumed);
- joints advance every TICK_S of controller time (the IRC5's 4 ms: EGM's fastest cycle, ABB "Application manual -
  Externally Guided Motion", 3HAC073319-001), synchronised on one trapezoid in the path parameter (the slowest
  axis sets the duration), so the same requests at the same ticks give the same joints bit for bit;
- num values are RAPID's 32-bit floats (RAPID manual, data type num: "a num is stored as a 32-bit float"), shown
  with 9 significant digits (which give the float back); joints are shown with 6 decimals;
- the event log records the state changes with RobotWare's event numbers (Operating manual - Troubleshooting IRC5,
  3HAC020738-001: 10010 Motors OFF state, 10011 Motors ON state, 10012 Safety guard stop state, 10013 Emergency stop
  state).
"""

from __future__ import annotations

import math
import re
import struct
import threading
from collections.abc import Callable, Sequence

from trackcal.drivers.abb.program import DONE, MOVE, SPEED, TARGET, joint_value

TICK_S = 0.004
ACCEL_S = 0.1  # time to reach the path speed (and to brake from it on a RAPID stop)
# ABB IRB 120 product specification (3HAC035960-001, "Performance": maximum axis speeds): axes 1-3 250 deg/s,
# axes 4-5 320 deg/s, axis 6 420 deg/s
IRB120_VMAX_DEG_S = (250.0, 250.0, 250.0, 320.0, 320.0, 420.0)
EVENTS = {
    "motoroff": (10010, "Motors OFF state"),
    "motoron": (10011, "Motors ON state"),
    "guardstop": (10012, "Safety guard stop state"),
    "emergencystop": (10013, "Emergency stop state"),
}
_JOINTTARGET = re.compile(r"^\s*\[\s*\[([^\]]*)\]\s*,\s*\[([^\]]*)\]\s*\]\s*$")


class RapidError(ValueError):
    """A value RAPID refuses (a syntax error in the value, a wrong type)."""


def as_num(text: str) -> float:
    """A RAPID num from its text, rounded to the 32-bit float RAPID stores."""
    try:
        v = float(text)
    except ValueError:
        raise RapidError(f"not a num: {text!r}") from None
    if not math.isfinite(v):
        raise RapidError(f"not a num: {text!r}")
    return struct.unpack("<f", struct.pack("<f", v))[0]


def num_text(v: float) -> str:
    return f"{v:.9g}"


def as_jointtarget(text: str) -> tuple[float, ...]:
    """The six robot axes of a jointtarget's RAPID text (the external axes are checked, not kept)."""
    m = _JOINTTARGET.match(text)
    if m is None:
        raise RapidError(f"not a jointtarget: {text!r}")
    rob, ext = m.group(1).split(","), m.group(2).split(",")
    if len(rob) != 6 or len(ext) != 6:
        raise RapidError(f"a jointtarget has 6 robot and 6 external axes: {text!r}")
    for v in ext:
        as_num(v)
    return tuple(as_num(v) for v in rob)


class Motion:
    """q(s) = q0 + (q1 - q0) s; s(t) a trapezoid of path speed sv (1/s) reached in ACCEL_S (a triangle when the path
    is too short), or, once braking, a ramp down at the same acceleration from where the brake began."""

    def __init__(self, q0: Sequence[float], q1: Sequence[float], pct: float, vmax: Sequence[float]) -> None:
        self.q0, self.q1 = tuple(q0), tuple(q1)
        d = [abs(b - a) for a, b in zip(q0, q1, strict=True)]
        sv = min((max(pct, 1.0) / 100.0 * v / x for x, v in zip(d, vmax, strict=True) if x > 0), default=0.0)
        self.t, self.s, self.v = 0.0, 0.0, 0.0
        self.brake: tuple[float, float, float] | None = None  # (t, s, v) where braking began
        if sv == 0.0:  # already there
            self.sa = self.ta = self.tc = self.total = 0.0
            self.s = 1.0
            return
        self.sa = sv / ACCEL_S
        if sv * ACCEL_S >= 1.0:
            self.ta, self.tc = math.sqrt(1.0 / self.sa), 0.0
        else:
            self.ta, self.tc = ACCEL_S, (1.0 - sv * ACCEL_S) / sv
        self.total = 2 * self.ta + self.tc

    def _profile(self, t: float) -> tuple[float, float]:
        if t >= self.total:
            return 1.0, 0.0
        if t < self.ta:
            return 0.5 * self.sa * t * t, self.sa * t
        peak = self.sa * self.ta
        if t < self.ta + self.tc:
            return 0.5 * peak * self.ta + peak * (t - self.ta), peak
        r = self.total - t
        return 1.0 - 0.5 * self.sa * r * r, self.sa * r

    def step(self, dt: float) -> tuple[float, ...]:
        self.t += dt
        if self.brake is None:
            self.s, self.v = self._profile(self.t)
        else:
            tb, sb, vb = self.brake
            r = min(self.t - tb, vb / self.sa)
            self.s, self.v = min(1.0, sb + vb * r - 0.5 * self.sa * r * r), max(0.0, vb - self.sa * r)
        return self.at()

    def start_braking(self) -> None:
        if self.brake is None and self.s < 1.0:
            self.brake = (self.t, self.s, self.v)

    @property
    def braking(self) -> bool:
        return self.brake is not None

    def at(self) -> tuple[float, ...]:
        if self.s >= 1.0:
            return self.q1
        return tuple(a + (b - a) * self.s for a, b in zip(self.q0, self.q1, strict=True))

    @property
    def arrived(self) -> bool:
        return self.s >= 1.0

    @property
    def standing(self) -> bool:
        return self.v == 0.0 and (self.arrived or self.braking)


class AbbController:
    """The controller; every method is thread-safe. `tick()` advances TICK_S of controller time."""

    def __init__(
        self,
        q0_deg: Sequence[float],
        seed: int = 0,
        vmax: Sequence[float] = IRB120_VMAX_DEG_S,
        limits_deg: Sequence[tuple[float, float]] | None = None,
    ) -> None:
        self.lock = threading.RLock()
        self.q = tuple(float(v) for v in q0_deg)
        self.vmax = tuple(vmax)
        self.limits = limits_deg
        self.seed = seed
        self.ctrlstate = "motoroff"
        self.opmode = "AUTO"
        self.execution = "stopped"
        self.pers = {TARGET: joint_value(self.q), SPEED: "10", MOVE: "0", DONE: "0"}
        self.motion: Motion | None = None
        self.ticks = 0
        self.elog: list[tuple[int, int, int, str, float]] = []  # (seqnum, msgtype, code, title, controller time)
        self.followers: list[Callable[[tuple[float, ...]], None]] = []
        self._event("motoroff")

    # --- panel -------------------------------------------------------------------------------------------------

    def _event(self, state: str, msgtype: int = 1) -> None:
        if state in EVENTS:
            code, title = EVENTS[state]
            self.elog.append((len(self.elog) + 1, msgtype, code, title, self.ticks * TICK_S))

    def _set_state(self, state: str) -> None:
        if state != self.ctrlstate:
            self.ctrlstate = state
            self._event(state, 1 if state in ("motoron", "motoroff") else 2)

    def set_ctrlstate(self, wanted: str) -> None:
        """RWS setctrlstate: motoron / motoroff, refused (RapidError) while a guard or emergency stop holds."""
        with self.lock:
            if wanted not in ("motoron", "motoroff"):
                raise RapidError(f"ctrl-state {wanted!r}: motoron or motoroff")
            if self.ctrlstate in ("guardstop", "emergencystop"):
                raise RapidError(f"refused in {self.ctrlstate}")
            if wanted == "motoroff":
                self._halt(brake=False)
            self._set_state(wanted)

    def fault(self, kind: str) -> None:
        """Injected by the mock's control port: guardstop, emergencystop (an immediate stop, drives off),
        motoroff, release (the stop reset: motors off), rapid_error (RAPID stops by itself)."""
        with self.lock:
            if kind in ("guardstop", "emergencystop", "motoroff"):
                self._halt(brake=False)
                self._set_state(kind)
            elif kind == "release":
                if self.ctrlstate in ("guardstop", "emergencystop", "emergencystopreset"):
                    self._set_state("motoroff")
            elif kind == "rapid_error":
                self._halt(brake=True)
            else:
                raise RapidError(f"unknown fault {kind!r}")

    # --- RAPID ------------------------------------------------------------------------------------------------

    def start(self) -> None:
        with self.lock:
            if self.ctrlstate != "motoron":
                raise RapidError("RAPID cannot start: motors off")
            self.execution = "running"

    def stop(self) -> None:
        with self.lock:
            self._halt(brake=True)

    def resetpp(self) -> None:
        with self.lock:
            if self.execution == "running":
                raise RapidError("resetpp refused while RAPID runs")
            self.motion = None

    def _halt(self, brake: bool) -> None:
        self.execution = "stopped"
        if self.motion is not None:
            if brake:
                self.motion.start_braking()
            else:
                self.q, self.motion = self.motion.at(), None

    def read(self, name: str) -> str:
        with self.lock:
            if name not in self.pers:
                raise KeyError(name)
            return self.pers[name]

    def write(self, name: str, value: str) -> None:
        with self.lock:
            if name not in self.pers:
                raise KeyError(name)
            if name == TARGET:
                q = as_jointtarget(value)
                self.pers[name] = joint_value(q)
            else:
                self.pers[name] = num_text(as_num(value))

    # --- motion -----------------------------------------------------------------------------------------------

    def tick(self) -> tuple[float, ...]:
        """One controller cycle: the motion advances, RAPID's loop goes on; returns the joints."""
        with self.lock:
            self.ticks += 1
            m = self.motion
            if m is not None and (self.execution == "running" or m.braking):
                self.q = m.step(TICK_S)
                if m.arrived and not m.braking:
                    self.motion = None
                    self.pers[DONE] = self.pers[MOVE]
                elif m.standing:  # braked to a stand: the program pointer stays at MoveAbsJ, a start goes on
                    self.motion = Motion(self.q, m.q1, as_num(self.pers[SPEED]), self.vmax)
            elif m is None and self.execution == "running" and self.pers[MOVE] != self.pers[DONE]:
                target = as_jointtarget(self.pers[TARGET])
                self.motion = Motion(self.q, target, min(100.0, max(0.0, as_num(self.pers[SPEED]))), self.vmax)
            q = self.q
        for follow in list(self.followers):
            follow(q)
        return q

    def snapshot(self) -> dict:
        with self.lock:
            m = self.motion
            planned = list(m.q1) if m is not None else list(self.q)
            moving = m is not None and (self.execution == "running" or not m.standing)
            return {
                "ctrlstate": self.ctrlstate,
                "opmode": self.opmode,
                "execution": self.execution,
                "q_deg": list(self.q),
                "pers": dict(self.pers),
                "ticks": self.ticks,
                "moving": moving,
                "planned_deg": planned,
            }
