"""ABB IRC5 client (drivers.interfaces.Robot) over Robot Web Services 1.0 (drivers.abb.rws) and the RAPID module
TrackcalRws (drivers.abb.program), which must be loaded in T_ROB1; trackcal starts it.

Resources used (ABB, "Application Manual - Robot Web Services", 3HAC050973-001, developercenter.robotstudio.com/api/
rwsApi/, the page of each in brackets):
- `rw/panel/opmode` ["Get Operation Mode"]: AUTO is required (in manual modes a write needs the FlexPendant's RMMP
  grant, and a calibration campaign runs the arm with nobody in the cell);
- `rw/panel/ctrlstate` ["Get Controller State", "Set Controller State": action=setctrlstate, ctrl-state=motoron]:
  motoron, motoroff, guardstop, emergencystop, emergencystopreset, sysfail, init;
- `rw/rapid/execution` ["Get RAPID Execution State": ctrlexecstate running|stopped; "Start RAPID Execution",
  "Stop RAPID Execution" (stopmode=stop), "Reset RAPID Program Pointer" (action=resetpp)];
- `rw/rapid/symbol/data/RAPID/T_ROB1/TrackcalRws/<name>` ["Get rapid variable current value", "Update rapid variable
  current value": action=set, value=...];
- `rw/motionsystem/mechunits/ROB_1/jointtarget` ["Get Joint target"]: rax_1..rax_6 in degrees;
- `rw/system` ["Get RobotWare System Information"] and `ctrl/identity` ["Get Controller Identity"]: the RobotWare
  version and the controller's serial number (ctrl-id), for the certificate.

A move writes trackcal_target and trackcal_speed, then trackcal_move (a new number): RAPID's MoveAbsJ ... fine runs
and sets trackcal_done to that number once the arm stands. While it runs the client polls, at least every GUARD_S
(25 Hz), the motion guard (the cell door, the E-stop input, a silent PLC), trackcal_done, the controller state and
the RAPID execution state. A reason to stop makes the client stop RAPID (stopmode=stop: a controlled stop on the
path, drives on) and the move end in DeviceFault with the StopCause's code ("stopped" for a plain reason or
`stop()`); the controller leaving motoron (guard stop, emergency stop, motors off) or RAPID stopping by itself ends
the move in DeviceFault with that code, latched in `state()` until `reset_faults()` finds it gone, turns the motors
on and starts RAPID again from `main` (the stopped move is not resumed: trackcal_done := trackcal_move first).

With `egm` (this PC's address and port for the controller's EGM position stream, drivers.abb.egm_link) the stream is
the joint monitor, as RSI is the KR C2's: a move is refused while it is stale, a stream that goes silent during a
move or a settle stops it (code egm_stale), and a settle is judged on its frames in controller time (one EGM cycle
each), the settled joints checked against RWS's (CHANNELS_DISAGREE). Without it, joints and settling come from RWS
polling every GUARD_S, the settle judged on the wall clock.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from trackcal.drivers.abb.egm_link import EGM_STALE, EgmLink
from trackcal.drivers.abb.program import DONE, MOVE, SPEED, TARGET, joint_value, symbol_path
from trackcal.drivers.abb.rws import DEFAULT_PASSWORD, DEFAULT_USER, RwsSession
from trackcal.drivers.errors import ConnectionLost, DeviceFault, DeviceTimeout
from trackcal.drivers.interfaces import JOINT_RESOLUTION_DEG, DeviceIdentity, RobotState, StopCause, stop_code
from trackcal.drivers.motion_request import checked_limits, checked_speed, checked_target
from trackcal.drivers.transport import SettleWindow, claim_socket, require_positive, require_settle_limits

AXES = ("axis 1", "axis 2", "axis 3", "axis 4", "axis 5", "axis 6")
GUARD_S = 0.04  # the guard, the answer and the controller's state are polled at least this often (25 Hz)
GUARD_SLICE_S = 0.01  # between two polls of the answer the guard is asked every 10 ms (the PLC's door: 100 Hz)
MAX_MOVE_ID = 1_000_000  # move numbers stay exact in a RAPID num (a 32-bit float: integers to 2**24)
# controller states (Robot Web Services manual, "Get Controller State") -> the fault code of a move they end
CTRL_FAULTS = {
    "motoroff": "motors_off",
    "guardstop": "guard_stop",
    "emergencystop": "emergency_stop",
    "emergencystopreset": "emergency_stop",
    "sysfail": "system_failure",
    "init": "motors_off",
}
RAPID_STOPPED = "rapid_stopped"  # RAPID stopped by itself (an error in the task, the FlexPendant's stop)
CHANNELS_DISAGREE = "monitor_disagrees"  # EGM's settled joints are not those RWS reports

CellBoxCheck = Callable[[tuple[float, ...]], "str | None"]
MotionGuard = Callable[[], "str | None"]


@dataclass(frozen=True)
class Identity:
    """What the certificate names of the controller."""

    serial: str  # ctrl/identity's ctrl-id (the controller's serial number)
    system: str  # rw/system's name
    robotware: str  # rw/system's rwversion


def claim_address(host: str, port: int) -> str:
    """The abstract Unix socket address (unix(7)) of this PC's claim on the controller at host:port (a controller is
    its RWS address: two mock controllers on one loopback address are two arms)."""
    return f"\0trackcal/abb/{host.strip().lower()}:{port}"


class AbbRws:
    """An ABB arm on an IRC5 controller with RobotWare 6, TrackcalRws loaded in T_ROB1, in AUTO mode."""

    def __init__(
        self,
        host: str,
        port: int = 80,
        *,
        user: str = DEFAULT_USER,
        password: str = DEFAULT_PASSWORD,
        joint_limits_deg: Sequence[tuple[float, float]] = ((-180.0, 180.0),) * 6,
        cell_box_check: CellBoxCheck | None = None,
        motion_guard: MotionGuard | None = None,
        connect_timeout_s: float = 30.0,
        move_timeout_s: float = 300.0,
        io_timeout_s: float = 5.0,
        egm: tuple[str, int] | None = None,
        egm_stale_s: float = 1.0,
    ) -> None:
        require_positive(
            connect_timeout_s=connect_timeout_s,
            move_timeout_s=move_timeout_s,
            io_timeout_s=io_timeout_s,
            egm_stale_s=egm_stale_s,
        )
        limits = checked_limits(joint_limits_deg, AXES)
        self.host, self.port = host, int(port)
        self.joint_limits_deg = limits
        self.cell_box_check = cell_box_check
        self.motion_guard = motion_guard
        self.connect_timeout_s = connect_timeout_s
        self.move_timeout_s = move_timeout_s
        self.io_timeout_s = io_timeout_s
        self.rws = RwsSession(host, port, user=user, password=password, io_timeout_s=io_timeout_s)
        self.device = self.rws.device
        # the EGM position stream this PC listens for (host, port), None: joints and settling by RWS polling only
        self.egm = None if egm is None else EgmLink(egm[0], egm[1], host, stale_s=egm_stale_s)
        self.controller_identity: Identity | None = None  # read by connect(): identity() is its interface's form
        self._next = 1
        self._motion = threading.Condition()  # guards the four below between the moving thread and stop()/state()
        self._moving: int | None = None
        self._stop_asked: str | None = None
        self._ended: tuple[int, bool] = (0, True)  # the last move's number, and whether the arm stood at its end
        self._fault = ""
        self._claim: socket.socket | None = None
        self.stop_sent_at: float | None = None  # time.monotonic() of the last RAPID stop sent (bench and tests)

    # --- connection -----------------------------------------------------------------------------------------

    def claim(self) -> None:
        """This PC's claim on the controller (an abstract Unix socket named after its address, released by the
        kernel when the process ends, kill -9 included): a second campaign on this PC is refused before it touches
        the arm. Idempotent."""
        if self._claim is not None:
            return
        self._claim = claim_socket(claim_address(self.host, self.port), self.device)

    def connect(self) -> None:
        """Reach the controller (retried until connect_timeout_s while it is not reachable), check AUTO mode and
        the module, read the identity; motors on and RAPID running unless a fault is latched (reset_faults)."""
        deadline = time.monotonic() + self.connect_timeout_s
        if self.egm is not None:
            self.egm.listen()
        while True:
            try:
                self.controller_identity = self._identity()
                break
            except (ConnectionLost, DeviceTimeout) as exc:
                if time.monotonic() >= deadline:
                    raise ConnectionLost(
                        f"not reachable within {self.connect_timeout_s:g} s: {exc}", device=self.device
                    ) from None
                time.sleep(0.2)
        mode = self._value("rw/panel/opmode", "opmode")
        if mode != "AUTO":
            raise DeviceFault(
                f"the controller is in {mode} mode: switch it to AUTO", code="not_auto", device=self.device
            )
        if self.egm is not None:
            self.egm.wait_first(max(0.1, deadline - time.monotonic()))
        done, move = self._num(DONE), self._num(MOVE)
        self._next = int(max(done, move)) % MAX_MOVE_ID + 1
        state = self._value("rw/panel/ctrlstate", "ctrlstate")
        if state in ("guardstop", "emergencystop", "emergencystopreset", "sysfail"):
            with self._motion:
                self._fault = state  # latched from before: the operator's acknowledged reset clears it
            return
        self._start()

    def _identity(self) -> Identity:
        system = self.rws.get("rw/system")[0]
        ident = self.rws.get("ctrl/identity")[0]
        return Identity(
            serial=str(ident.get("ctrl-id", "")),
            system=str(system.get("name", "")),
            robotware=str(system.get("rwversion", "")),
        )

    def identity(self) -> DeviceIdentity:
        """The controller's serial number (ctrl/identity's ctrl-id), its system's name and RobotWare version
        (rw/system), read from it (at connect(), or now)."""
        ident = self.controller_identity or self._identity()
        return DeviceIdentity(ident.serial, f"IRC5 system {ident.system}", f"RobotWare {ident.robotware}")

    def close(self) -> None:
        self.rws.close()
        if self.egm is not None:
            self.egm.close()
        if self._claim is not None:
            self._claim.close()
            self._claim = None

    def __enter__(self) -> AbbRws:
        self.connect()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # --- RWS helpers ----------------------------------------------------------------------------------------------

    def _value(self, path: str, key: str) -> str:
        items = self.rws.get(path)
        if not items or key not in items[0]:
            raise DeviceFault(f"{path}: no {key} in the answer", code="protocol", device=self.device)
        return str(items[0][key])

    def _num(self, name: str) -> float:
        text = self._value(symbol_path(name), "value")
        try:
            return float(text)
        except ValueError:
            raise DeviceFault(f"RAPID {name} = {text!r} is not a num", code="protocol", device=self.device) from None

    def _set(self, name: str, value: str) -> None:
        self.rws.post(symbol_path(name), {"action": "set"}, {"value": value})

    def _start(self) -> None:
        """Motors on and RAPID running from main, the last move counted as done (never resumed)."""
        if self._value("rw/panel/ctrlstate", "ctrlstate") != "motoron":
            self.rws.post("rw/panel/ctrlstate", {"action": "setctrlstate"}, {"ctrl-state": "motoron"})
        if self._value("rw/rapid/execution", "ctrlexecstate") == "running":
            return
        self.rws.post("rw/rapid/execution", {"action": "resetpp"})
        self._set(DONE, f"{self._num(MOVE):.0f}")
        self.rws.post(
            "rw/rapid/execution",
            {"action": "start"},
            {
                "regain": "continue",
                "execmode": "continue",
                "cycle": "forever",
                "condition": "none",
                "stopatbp": "disabled",
                "alltaskbytsp": "false",
            },
        )

    # --- Robot protocol -------------------------------------------------------------------------------------

    def joints(self) -> tuple[float, ...]:
        """Actual joints (deg, 4 decimals): ROB_1's jointtarget."""
        item = self.rws.get("rw/motionsystem/mechunits/ROB_1/jointtarget")[0]
        try:
            return tuple(round(float(item[f"rax_{i}"]), 4) for i in range(1, 7))
        except (KeyError, ValueError):
            raise DeviceFault(
                f"jointtarget without 6 numeric axes: {item}", code="protocol", device=self.device
            ) from None

    def check_target(self, target_deg: Sequence[float]) -> tuple[float, ...]:
        """The target as a tuple, or MotionRefused (joint limits first, then the cell box)."""
        return checked_target(target_deg, AXES, self.joint_limits_deg, self.cell_box_check, self.device)

    def move(self, target_deg: tuple[float, ...], speed_override_pct: float) -> None:
        target = self.check_target(target_deg)
        speed = checked_speed(speed_override_pct, self.device)
        with self._motion:
            if self._fault:
                raise DeviceFault(
                    f"move refused: {self._fault} latched (acknowledge to reset)", code="latched", device=self.device
                )
        if self.egm is not None:
            self.egm.require_fresh()  # never move without the monitor
        number, self._next = self._next, self._next % MAX_MOVE_ID + 1
        with self._motion:
            self._moving, self._stop_asked = number, None
        stood = False
        try:
            stopped = None
            for name, value in ((TARGET, joint_value(target)), (SPEED, f"{round(speed):d}"), (MOVE, f"{number:d}")):
                stopped = self._guard()  # asked before each write: a door opened now needs no stop, nothing moved
                if stopped:
                    break
                self._set(name, value)
            stopped = stopped or self._await_done(number)
            stood = True
        finally:
            with self._motion:
                self._moving, self._ended = None, (number, stood)
                self._motion.notify_all()
        if stopped:
            raise DeviceFault(
                f"move {number} to {target} stopped: {stopped}", code=stop_code(stopped), device=self.device
            )

    def _await_done(self, number: int) -> str | None:
        """Poll until RAPID answers move `number` (None), or the guard stops it (its reason, once the arm stands);
        DeviceFault when the controller stops the move itself, DeviceTimeout after move_timeout_s. The guard is asked
        before every request (each one an HTTP round trip), so a door opened is acted on within one of them."""
        deadline = time.monotonic() + self.move_timeout_s
        seen: dict[str, str] = {}
        steps = (
            lambda: self._num(DONE) == number,
            lambda: seen.update(execution=self._value("rw/rapid/execution", "ctrlexecstate")),
            lambda: self._check_controller(f"move {number}", seen["execution"]),
        )
        while True:
            started = time.monotonic()
            for step in steps:
                reason = self._guard()
                if reason:
                    self._halt()
                    return reason
                if step():
                    return None
            if started > deadline:
                raise DeviceTimeout(f"move {number} not done within {self.move_timeout_s:g} s", device=self.device)
            while time.monotonic() - started < GUARD_S:
                reason = self._guard()
                if reason:
                    self._halt()
                    return reason
                time.sleep(GUARD_SLICE_S)

    def _check_controller(self, what: str, execution: str | None = None) -> None:
        """DeviceFault (latched) when the controller left motoron or RAPID stopped; `execution` the RAPID execution
        state read just before (read here when not given): first, so that a stop that explains it shows next."""
        if execution is None:
            execution = self._value("rw/rapid/execution", "ctrlexecstate")
        state = self._value("rw/panel/ctrlstate", "ctrlstate")
        code = CTRL_FAULTS.get(state)
        if code is None and execution != "running":
            state, code = "RAPID stopped", RAPID_STOPPED
        if code is not None:
            with self._motion:
                self._fault = state
            raise DeviceFault(f"{what} ended by the controller: {state}", code=code, device=self.device)

    def _halt(self) -> None:
        """Stop RAPID (a controlled stop on the path) and wait until it reports stopped and the arm stands."""
        self.stop_sent_at = time.monotonic()
        self.rws.post("rw/rapid/execution", {"action": "stop"}, {"stopmode": "stop", "usetsp": "normal"})
        deadline = time.monotonic() + self.io_timeout_s
        last = None
        while True:
            q = self.joints()
            if self._value("rw/rapid/execution", "ctrlexecstate") == "stopped" and q == last:
                break
            if time.monotonic() > deadline:
                raise DeviceTimeout(
                    f"the arm did not stand within {self.io_timeout_s:g} s of the RAPID stop", device=self.device
                )
            last = q
            time.sleep(GUARD_S)
        with self._motion:
            self._fault = "RAPID stopped by trackcal"

    def _guard(self) -> str | None:
        if self.motion_guard is not None:
            reason = self.motion_guard()
            if reason:
                return reason
        if self.egm is not None:
            stale = self.egm.stale()
            if stale:
                return StopCause(f"the EGM stream stopped ({stale})", EGM_STALE)
        with self._motion:
            return self._stop_asked

    def wait_settled(self, tolerance_deg: float, window_s: float, timeout_s: float) -> tuple[float, ...]:
        """Joints read every GUARD_S that stay within tolerance_deg of the window's first for window_s (wall clock);
        the motion guard polled as often (DeviceFault with its code), the controller's state checked."""
        require_settle_limits(tolerance_deg, window_s, timeout_s)
        if self.egm is not None:
            return self._settle_on_egm(self.egm, tolerance_deg, window_s, timeout_s)
        deadline = time.monotonic() + timeout_s
        anchor: tuple[float, ...] | None = None
        since = 0.0
        while True:
            now = time.monotonic()
            reason = self._guard()
            if reason:
                raise DeviceFault(f"settling stopped: {reason}", code=stop_code(reason), device=self.device)
            self._check_controller("settling")
            q = self.joints()
            if anchor is None or any(abs(a - b) > tolerance_deg for a, b in zip(q, anchor, strict=True)):
                anchor, since = q, now
            elif now - since >= window_s - 1e-9:
                return q
            if now > deadline:
                raise DeviceTimeout(
                    f"joints not settled within {tolerance_deg} deg over {window_s} s after {timeout_s} s",
                    device=self.device,
                )
            time.sleep(max(0.0, min(GUARD_S, window_s) - (time.monotonic() - now)))

    def _settle_on_egm(self, egm: EgmLink, tolerance_deg: float, window_s: float, timeout_s: float) -> tuple:
        """Settling judged on EGM frames arriving after the call, one EGM cycle of controller time each; the joints
        RWS reports then must agree with the stream's (CHANNELS_DISAGREE otherwise: the stream is not this arm's)."""
        cycle = egm.cycle_s
        real_deadline = time.monotonic() + timeout_s + egm.stale_s
        next_seq = egm.last_seq + 1
        window = SettleWindow(tolerance_deg, window_s, timeout_s, cycle, next_seq, self.device)
        while True:
            reason = self._guard()
            if reason:
                raise DeviceFault(f"settling stopped: {reason}", code=stop_code(reason), device=self.device)
            for seq, frame in egm.frames_from(next_seq):
                next_seq = seq + 1
                q = tuple(round(v, 4) for v in frame.joints_deg)
                if window.settled(seq, q):
                    self._check_channels(q, tolerance_deg)
                    return q
            if time.monotonic() > real_deadline:
                raise DeviceTimeout("EGM frames stopped coming while waiting to settle", device=self.device)
            egm.wait_for_frame(next_seq, GUARD_S)

    def _check_channels(self, settled: tuple[float, ...], tolerance_deg: float) -> None:
        rws = self.joints()
        allowed = tolerance_deg + JOINT_RESOLUTION_DEG
        for name, e, r in zip(AXES, settled, rws, strict=True):
            if abs(e - r) > allowed + 1e-9:
                raise DeviceFault(
                    f"EGM and RWS disagree on {name}: EGM {e:.4f} deg, RWS {r:.4f} deg (more than "
                    f"{allowed:g} deg apart): is the EGM stream this arm's?",
                    code=CHANNELS_DISAGREE,
                    device=self.device,
                )

    def stop(self) -> None:
        """Brake the running move (the moving thread stops RAPID within GUARD_S); returns once the arm stands. A
        no-op when no move runs."""
        bound = GUARD_S + 3 * self.io_timeout_s
        with self._motion:
            number = self._moving
            if number is None:
                return
            self._stop_asked = "stop requested"
            ended = self._motion.wait_for(lambda: self._moving != number, timeout=bound)
            stood = self._ended == (number, True)
        if not ended or not stood:
            raise DeviceTimeout(f"move {number} not stopped within {bound:g} s", device=self.device)

    def state(self) -> RobotState:
        with self._motion:
            return RobotState(moving=self._moving is not None, fault=self._fault)

    def reset_faults(self) -> None:
        """After the operator acknowledged: DeviceFault if the controller still holds a guard or emergency stop;
        else motors on and RAPID started again from main (the stopped move not resumed)."""
        state = self._value("rw/panel/ctrlstate", "ctrlstate")
        if state in ("guardstop", "emergencystop", "emergencystopreset", "sysfail"):
            raise DeviceFault(
                f"the controller is still in {state}: reset it on the cell, then acknowledge",
                code=CTRL_FAULTS[state],
                device=self.device,
            )
        self._start()
        with self._motion:
            self._fault = ""
