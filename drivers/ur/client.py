"""Universal Robots client (drivers.interfaces.Robot) over SDU Robotics' ur_rtde (PyPI `ur-rtde`, pinned 1.6.5).

trackcal writes no RTDE client of its own: the three ur_rtde interfaces do the wire work (their API:
sdurobotics.gitlab.io/ur_rtde/api/api.html; the Python names are those of src/rtde_python_bindings.cpp):

- DashboardClient (port 29999): `polyscopeVersion`, `isInRemoteControl` (PolyScope 5.6 and later: a robot in local
  control accepts no remote program), `unlockProtectiveStop`, `closeSafetyPopup`, `closePopup`, and for the
  controller's identity `getSerialNumber` (PolyScope 5.6 and later) and `getRobotModel` (Universal Robots,
  "Dashboard Server e-Series": the commands and their replies).
- RTDEReceiveInterface (port 30004): the stream trackcal reads, at the controller's rate (500 Hz e-Series, 125 Hz
  CB3): `getActualQ` (rad), `getActualTCPPose` (m, rotation vector rad), `getRobotMode`, `getSafetyMode`,
  `getSafetyStatusBits`, `getTimestamp` (controller time, s).
- RTDEControlInterface (port 30004 + ur_rtde's control script written to port 30003): `moveJ(q, speed, acceleration,
  asynchronous=True)`, `stopJ(deceleration, asynchronous=False)`, `isProgramRunning`, `reuploadScript` (ur_rtde's
  documented recovery after a protective stop: unlock it through the dashboard, then upload the script again).

Enumerations (Universal Robots, "Real-Time Data Exchange (RTDE) Guide", outputs robot_mode, safety_mode,
safety_status_bits): robot_mode 7 RUNNING (3 POWER_OFF, 5 IDLE: brakes held); safety_status_bits bit 0 normal,
bit 2 protective stopped, bit 4 safeguard stopped, bits 5/6/7 system / robot / any emergency stop, bit 8 violation,
bit 9 fault.

A move is asynchronous (moveJ with asynchronous=True) so that the client keeps the arm in view: every POLL_S (one
RTDE cycle at 500 Hz) it reads the stream and polls the motion guard (the cell door, campaign/cells/checks.py); a
reason to stop sends stopJ at once, so the robot is braking within two RTDE cycles of the guard noticing, and the
move ends in DeviceFault code "stopped" once the arm stands. A protective stop raised by the robot itself ends the
move in DeviceFault code "protective_stop", latched in state() until reset_faults() clears it (dashboard unlock,
popup closed, script uploaded again). The move is over when the arm stands at the target: the joints reported
(degrees, rounded to the interface's 0.0001 deg) equal the target within `target_tolerance_deg`, the trust rule of
issue 27; an arm that stands still elsewhere for `stall_s` is a DeviceFault code "target_mismatch", so the
campaign stops before anything is measured at the wrong pose.

Units: degrees and millimetres at this interface, radians and metres to ur_rtde. Every failure (nothing reachable,
a lost connection, a stale stream, a robot in local control, a refused command) is one DeviceError line naming the
robot's address.
"""

from __future__ import annotations

import contextlib
import math
import os
import socket
import sys
import threading
import time
from collections.abc import Callable, Sequence

import dashboard_client
import rtde_control
import rtde_receive

from trackcal.drivers.errors import ConnectionLost, DeviceError, DeviceFault, DeviceTimeout
from trackcal.drivers.interfaces import DeviceIdentity, RobotState, stop_code
from trackcal.drivers.motion_request import checked_limits, checked_speed, checked_target
from trackcal.drivers.transport import claim_socket, require_settle_limits

AXES = ("base", "shoulder", "elbow", "wrist 1", "wrist 2", "wrist 3")
POLL_S = 0.002  # one RTDE cycle at 500 Hz (e-Series); the guard and the stream are read this often during moves
RESOLUTION_DEG = 1e-4  # joint angles cross the Robot interface at 4 decimals of a degree (drivers.interfaces)
# the most ur_rtde's moveJ takes (rtde_control_interface.h: UR_JOINT_VELOCITY_MAX 3.14 rad/s, UR_JOINT_ACCELERATION_MAX
# 40 rad/s^2; a larger value is a ValueError before anything is sent): the hardware file's bounds (drivers/ur/family.py)
MOVEJ_SPEED_MAX_DEG_S = math.degrees(3.14)
MOVEJ_ACCELERATION_MAX_DEG_S2 = math.degrees(40.0)

# RTDE Guide enumerations (see the module docstring)
ROBOT_MODES = {
    -1: "no controller",
    0: "disconnected",
    1: "confirm safety",
    2: "booting",
    3: "power off",
    4: "power on",
    5: "idle (brakes held)",
    6: "backdrive",
    7: "running",
    8: "updating firmware",
}
ROBOT_RUNNING = 7
SERIAL_SINCE = (5, 6)  # the dashboard's `get serial number` (PolyScope 5.6 and later, see UrRtde.identity)
SAFETY_BITS = (
    (2, "protective stop"),
    (4, "safeguard stop"),
    (5, "system emergency stop"),
    (6, "robot emergency stop"),
    (7, "emergency stop"),
    (8, "safety violation"),
    (9, "safety fault"),
)
PROTECTIVE_STOP_BIT = 2
# a refused moveJ looks this long for a safety stop that explains it (the receive interface trails the control one by
# a frame or two: 16 ms at 125 Hz; 0.5 s leaves room for a loaded machine)
REFUSAL_LOOK_S = 0.5
EMERGENCY_BITS = (5, 6, 7)

_LOST_LINKS: list = []  # ur_rtde interfaces of lost links, never touched again (see UrRtde.close)

CellBoxCheck = Callable[[tuple[float, ...]], "str | None"]
MotionGuard = Callable[[], "str | None"]


def _version_major_minor(text: str) -> tuple[int, int]:
    """(major, minor) of a PolyScope version reply ("URSoftware 5.11.1.108318 (Jan 16 2024)" or "5.11.1.108318")."""
    for word in str(text).split():
        parts = word.split(".")
        if len(parts) >= 2 and parts[0].isdigit() and parts[1].isdigit():
            return int(parts[0]), int(parts[1])
    return (0, 0)


_DIVERTED: list[str] = []  # the log native output went to (once per process)


def divert_native_output(log_path: str | os.PathLike) -> bool:
    """Keep ur_rtde's own console lines off trackcal's console: they go to log_path (appended). Its C++ threads write
    them to the process's file descriptors 2 and 1 whatever the constructors' `verbose` flag says (std::cerr in
    src/rtde_receive_interface.cpp's receive thread, "RTDEReceiveInterface boost system Exception: ...";
    std::cerr / std::cout in src/rtde_control_interface.cpp, "RTDEControlInterface: Could not receive data from
    robot...", "Reconnecting..."), so the descriptors move: Python's sys.stdout and sys.stderr are re-opened on
    duplicates of fds 1 and 2 (the console, where trackcal's own lines stay), then fds 1 and 2 point at the log.
    Only when sys.stdout / sys.stderr are fds 1 and 2 themselves (a command line; not under a capturing test
    runner), once per process; returns whether the output is diverted."""
    if _DIVERTED:
        return True
    try:
        if sys.stdout.fileno() != 1 or sys.stderr.fileno() != 2:
            return False
    except (AttributeError, OSError, ValueError):  # io.UnsupportedOperation is an OSError and a ValueError
        return False
    log = os.open(os.fspath(log_path), os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    streams = []
    for fd, stream in ((1, sys.stdout), (2, sys.stderr)):
        stream.flush()
        kept = {"encoding": stream.encoding, "errors": stream.errors, "buffering": 1 if stream.line_buffering else -1}
        streams.append(open(os.dup(fd), "w", **kept))  # noqa: SIM115
    os.dup2(log, 1)
    os.dup2(log, 2)
    os.close(log)
    sys.stdout, sys.stderr = streams
    _DIVERTED.append(os.fspath(log_path))
    return True


def claim_address(host: str) -> str:
    """The abstract Unix socket address (a leading NUL, unix(7)) of this PC's claim on the controller at host."""
    return f"\0trackcal/ur/{host.strip().lower()}"


class UrRtde:
    """A Universal Robots arm (CB3 or e-Series) driven through ur_rtde; `host` is the controller's address, the
    only peer trackcal connects to (the hardware file's robot.host)."""

    def __init__(
        self,
        host: str,
        *,
        joint_limits_deg: Sequence[tuple[float, float]] = ((-360.0, 360.0),) * 6,
        cell_box_check: CellBoxCheck | None = None,
        motion_guard: MotionGuard | None = None,
        connect_timeout_s: float = 30.0,
        move_timeout_s: float = 300.0,
        io_timeout_s: float = 5.0,
        stale_s: float = 1.0,
        joint_speed_deg_s: float = 60.0,
        joint_acceleration_deg_s2: float = 80.0,
        stop_deceleration_deg_s2: float = 229.0,
        target_tolerance_deg: float = RESOLUTION_DEG,
        stall_s: float = 1.0,
        unlock_timeout_s: float = 10.0,
    ) -> None:
        for name, v in (
            ("connect_timeout_s", connect_timeout_s),
            ("move_timeout_s", move_timeout_s),
            ("io_timeout_s", io_timeout_s),
            ("stale_s", stale_s),
            ("joint_speed_deg_s", joint_speed_deg_s),
            ("joint_acceleration_deg_s2", joint_acceleration_deg_s2),
            ("stop_deceleration_deg_s2", stop_deceleration_deg_s2),
            ("target_tolerance_deg", target_tolerance_deg),
            ("stall_s", stall_s),
            ("unlock_timeout_s", unlock_timeout_s),
        ):
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        limits = checked_limits(joint_limits_deg, AXES)
        self.host = host
        self.device = f"UR {host}"
        self.joint_limits_deg = limits
        self.cell_box_check = cell_box_check
        self.motion_guard = motion_guard
        self.connect_timeout_s = connect_timeout_s
        self.move_timeout_s = move_timeout_s
        self.io_timeout_s = io_timeout_s
        self.stale_s = stale_s
        self.joint_speed_deg_s = joint_speed_deg_s  # at 100 % speed override (ur_rtde's moveJ default: 1.05 rad/s)
        self.joint_acceleration_deg_s2 = joint_acceleration_deg_s2  # ur_rtde's moveJ default 1.4 rad/s2 = 80 deg/s2
        self.stop_deceleration_deg_s2 = stop_deceleration_deg_s2  # stopJ: 4 rad/s2 (ur_rtde's default 2, max 40)
        self.target_tolerance_deg = target_tolerance_deg
        self.stall_s = stall_s
        self.unlock_timeout_s = unlock_timeout_s
        self.dashboard = None
        self.receive = None
        self.control = None
        self.version: tuple[int, int] = (0, 0)
        self._lock = threading.Condition()  # guards the three below between the moving thread and stop()/state()
        self._moving = False
        self._stop_asked: str | None = None
        self._fault = ""  # latched until reset_faults: a protective stop seen during a move
        self.stop_sent_at: float | None = None  # time.monotonic() of the last stopJ sent (bench and tests)
        self.stop_seen: float | None = None  # controller time of the last frame read before that stopJ
        self._last_stamp: float | None = None
        self._claim: socket.socket | None = None

    # --- connection -----------------------------------------------------------------------------------------

    def claim(self) -> None:
        """Hold this PC's claim on the controller at `host` until close(): an abstract Unix socket named after the
        address (Linux, unix(7): no file, released by the kernel when the process ends, kill -9 included). The arm
        runs one control script: every RTDEControlInterface uploads its own when constructed (ur_rtde's docs,
        "Introduction": the control interface "requires a control script to be running on the robot, which is
        uploaded automatically"; src/rtde_control_interface.cpp), so a second campaign would take the arm over from
        the first. A second claim on this PC raises ConnectionLost
        whose cause is OSError EADDRINUSE, before anything touches the robot. Idempotent."""
        if self._claim is not None:
            return
        self._claim = claim_socket(claim_address(self.host), self.device)

    def connect(self) -> None:
        """Dashboard first (version, remote control), then the RTDE stream, then the control script; retried until
        connect_timeout_s while the controller is not reachable yet (it may be booting)."""
        if self.receive is not None:
            return
        deadline = time.monotonic() + self.connect_timeout_s
        last: Exception | None = None
        while True:
            try:
                self._open()
                return
            except DeviceFault:
                self.close()
                raise
            except DeviceError as exc:
                self._disconnect()  # the claim is kept while retrying
                last = exc
            if time.monotonic() >= deadline:
                raise ConnectionLost(f"not reachable within {self.connect_timeout_s:g} s: {last}", device=self.device)
            time.sleep(0.2)

    def _open(self) -> None:
        try:
            self.dashboard = dashboard_client.DashboardClient(self.host)
            self.dashboard.connect()
        except RuntimeError as exc:
            raise ConnectionLost(f"dashboard server (port 29999): {exc}", device=self.device) from None
        self.version = _version_major_minor(self._dash("polyscopeVersion"))
        if self.version >= (5, 6) and not self._dash("isInRemoteControl"):
            raise DeviceFault(
                "the robot is in local control: switch the teach pendant to Remote Control",
                code="local_control",
                device=self.device,
            )
        try:
            self.receive = rtde_receive.RTDEReceiveInterface(self.host)
        except RuntimeError as exc:
            raise ConnectionLost(f"RTDE stream (port 30004): {exc}", device=self.device) from None
        if self.protective_stopped():  # latched from before (a resumed campaign): reset_faults starts the script
            with self._lock:
                self._fault = "protective stop"
            return
        self._require_running("cannot start the control script")
        self._start_control()

    def _start_control(self) -> None:
        try:
            self.control = rtde_control.RTDEControlInterface(self.host)
        except RuntimeError as exc:
            text = str(exc)
            if "remote" in text.lower():
                raise DeviceFault(
                    f"the robot refuses remote control: {text}", code="local_control", device=self.device
                ) from None
            raise ConnectionLost(f"control script (ports 30003 / 30004): {text}", device=self.device) from None

    def _dash(self, name: str, *args):
        if self.dashboard is None:
            raise ConnectionLost("not connected (call connect() first)", device=self.device)
        try:
            return getattr(self.dashboard, name)(*args)
        except RuntimeError as exc:
            raise ConnectionLost(f"dashboard {name}: {exc}", device=self.device) from None

    def identity(self) -> DeviceIdentity:
        """The controller's serial number, robot model and PolyScope version, read from its dashboard server: the
        replies to `get serial number`, `get robot model` and `PolyscopeVersion` (Universal Robots, "Dashboard Server
        e-Series"; `get serial number` from PolyScope 5.6 on: ur_rtde's DashboardClient.getSerialNumber sends it only
        then and checks that the reply is a number, src/dashboard_client.cpp; its polyscopeVersion() keeps the
        version number of the reply "URSoftware 5.11.1.108318 (...)"). An older PolyScope's serial is ""."""
        serial = self._dash("getSerialNumber") if self.version >= SERIAL_SINCE else ""
        return DeviceIdentity(
            str(serial).strip(),
            f"Universal Robots {str(self._dash('getRobotModel')).strip()}",
            f"PolyScope {str(self._dash('polyscopeVersion')).strip()}",
        )

    def close(self) -> None:
        """Disconnect and give up the claim."""
        self._disconnect()
        if self._claim is not None:
            self._claim.close()
            self._claim = None

    def _disconnect(self) -> None:
        # ur_rtde 1.6.5 after a lost link: disconnect() of its interfaces (and their destructors) can crash the
        # process (tests/test_ur_driver.py, dropped connection); a lost link's interfaces are kept, untouched, until
        # the process ends
        lost = self.receive is not None and not _connected(self.receive)
        lost = lost or (self.control is not None and not _connected(self.control))
        devices = [(name, getattr(self, name)) for name in ("receive", "dashboard", "control")]
        self.receive = self.dashboard = self.control = None
        if lost:
            _LOST_LINKS.extend(dev for _, dev in devices if dev is not None)
            return
        for name, dev in devices:
            if dev is not None and not _bounded(lambda d=dev, n=name: _shut(d, n == "control"), self.io_timeout_s):
                _LOST_LINKS.append(dev)  # still inside its call: never touched again

    def __enter__(self) -> UrRtde:
        self.connect()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # --- the stream -----------------------------------------------------------------------------------------

    def _rx(self):
        if self.receive is None:
            raise ConnectionLost("not connected (call connect() first)", device=self.device)
        if not self.receive.isConnected():
            raise ConnectionLost("the RTDE stream closed (port 30004)", device=self.device)
        return self.receive

    def _sample(self) -> tuple[float, tuple[float, ...], int]:
        """(controller timestamp s, joints rad, safety status bits) of the latest frame."""
        rx = self._rx()
        try:
            out = float(rx.getTimestamp()), tuple(float(v) for v in rx.getActualQ()), int(rx.getSafetyStatusBits())
        except RuntimeError as exc:
            raise ConnectionLost(f"RTDE stream: {exc}", device=self.device) from None
        self._last_stamp = out[0]
        return out

    def joints(self) -> tuple[float, ...]:
        """Actual joints (deg, 4 decimals): actual_q of the latest RTDE frame."""
        return to_deg(self._sample()[1])

    def tcp_pose(self) -> tuple[float, ...]:
        """Actual TCP pose of the controller's own model: x, y, z (mm) and the rotation vector (deg)."""
        try:
            p = self._rx().getActualTCPPose()
        except RuntimeError as exc:
            raise ConnectionLost(f"RTDE stream: {exc}", device=self.device) from None
        return (*(1000.0 * float(v) for v in p[:3]), *(math.degrees(float(v)) for v in p[3:]))

    def robot_mode(self) -> int:
        return int(self._rx().getRobotMode())

    def safety_mode(self) -> int:
        return int(self._rx().getSafetyMode())

    def safety_status_bits(self) -> int:
        return int(self._rx().getSafetyStatusBits())

    def protective_stopped(self) -> bool:
        return bool(self.safety_status_bits() >> PROTECTIVE_STOP_BIT & 1)

    def _safety_text(self, bits: int) -> str:
        return ", ".join(text for bit, text in SAFETY_BITS if bits >> bit & 1)

    def _explain_refusal(self, target: tuple[float, ...]) -> None:
        """A moveJ the control script did not accept: when the robot raised a protective or emergency stop meanwhile
        (the script stops with it; the receive interface shows it a frame or two later), that is the cause, and it
        is latched as a move ended by it would be."""
        deadline = time.monotonic() + REFUSAL_LOOK_S
        while True:
            bits = self.safety_status_bits()
            if bits >> PROTECTIVE_STOP_BIT & 1 or any(bits >> b & 1 for b in EMERGENCY_BITS):
                why = self._safety_text(bits)
                with self._lock:
                    self._fault = why
                raise DeviceFault(
                    f"move to {target} refused by the robot: {why}", code="protective_stop", device=self.device
                )
            if time.monotonic() >= deadline:
                return
            time.sleep(0.008)  # an RTDE cycle at 125 Hz

    def _require_running(self, what: str) -> None:
        mode = self.robot_mode()
        bits = self.safety_status_bits()
        why = self._safety_text(bits)
        if why:
            raise DeviceFault(f"{what}: {why}", code="safety", device=self.device)
        if mode != ROBOT_RUNNING:
            raise DeviceFault(
                f"{what}: robot mode {ROBOT_MODES.get(mode, mode)} (power on and release the brakes on "
                "the teach pendant)",
                code="robot_mode",
                device=self.device,
            )

    # --- Robot protocol -------------------------------------------------------------------------------------

    def check_target(self, target_deg: Sequence[float]) -> tuple[float, ...]:
        """The target as a tuple, or MotionRefused (joint limits first, then the cell box)."""
        return checked_target(target_deg, AXES, self.joint_limits_deg, self.cell_box_check, self.device)

    def move(self, target_deg: tuple[float, ...], speed_override_pct: float) -> None:
        target = self.check_target(target_deg)
        speed = checked_speed(speed_override_pct, self.device)
        self._require_running(f"move to {target} refused")
        reason = None if self.motion_guard is None else self.motion_guard()
        if reason:
            raise DeviceFault(f"move to {target} refused: {reason}", code=stop_code(reason), device=self.device)
        with self._lock:
            self._moving, self._stop_asked = True, None
        try:
            self._move(target, round(speed) / 100.0)
        finally:
            with self._lock:
                self._moving = False
                self._lock.notify_all()

    def _move(self, target: tuple[float, ...], fraction: float) -> None:
        q = [math.radians(v) for v in target]
        if self.control is None:
            raise ConnectionLost("not connected (call connect() first)", device=self.device)
        try:
            accepted = self.control.moveJ(
                q, math.radians(self.joint_speed_deg_s) * fraction, math.radians(self.joint_acceleration_deg_s2), True
            )
        except RuntimeError as exc:
            raise ConnectionLost(f"moveJ to {target}: {exc}", device=self.device) from None
        if not accepted:
            self._explain_refusal(target)
            raise DeviceFault(
                f"moveJ to {target} not accepted by the control script", code="refused", device=self.device
            )
        deadline = time.monotonic() + self.move_timeout_s
        stamp, fresh_at = None, time.monotonic()
        still_since, last_q, last_t = None, None, None
        while True:
            now = time.monotonic()
            reason = self._guard()
            if reason:
                self._brake()
                raise DeviceFault(f"move to {target} stopped: {reason}", code=stop_code(reason), device=self.device)
            t, q_now, bits = self._sample()
            if bits >> PROTECTIVE_STOP_BIT & 1 or any(bits >> b & 1 for b in EMERGENCY_BITS):
                why = self._safety_text(bits)
                with self._lock:
                    self._fault = why
                raise DeviceFault(
                    f"move to {target} ended by the robot: {why}", code="protective_stop", device=self.device
                )
            if t != stamp:
                stamp, fresh_at = t, now
            elif now - fresh_at > self.stale_s:
                self._brake_quietly()
                raise DeviceTimeout(
                    f"no RTDE frame for {self.stale_s:g} s during the move to {target}", device=self.device
                )
            deg = to_deg(q_now)
            still = last_q is not None and t != last_t and _alike(q_now, last_q)  # two frames alike: it stands
            if still and all(abs(a - b) <= self.target_tolerance_deg + 1e-9 for a, b in zip(deg, target, strict=True)):
                return
            if still:
                still_since = still_since if still_since is not None else now
                if now - still_since > self.stall_s and not self._async_running():
                    off = max(abs(a - b) for a, b in zip(deg, target, strict=True))
                    raise DeviceFault(
                        f"the robot stands at {deg}, not at the target {target} (off by {off:.4f} deg): "
                        "nothing measured there",
                        code="target_mismatch",
                        device=self.device,
                    )
            elif t != last_t:
                still_since = None
            if t != last_t:
                last_q, last_t = q_now, t
            if now > deadline:
                self._brake_quietly()
                raise DeviceTimeout(f"move to {target} not done within {self.move_timeout_s:g} s", device=self.device)
            time.sleep(POLL_S)

    def _async_running(self) -> bool:
        """Whether ur_rtde's control script still runs an asynchronous move (its progress register is >= 0)."""
        try:
            return self.control.getAsyncOperationProgress() >= 0
        except RuntimeError:
            return False

    def _guard(self) -> str | None:
        if self.motion_guard is not None:
            reason = self.motion_guard()
            if reason:
                return reason
        with self._lock:
            return self._stop_asked

    def _brake(self) -> None:
        """stopJ at the stop deceleration; returns once the script has brought the arm to a stand."""
        self.stop_sent_at, self.stop_seen = time.monotonic(), self._last_stamp
        try:
            self.control.stopJ(math.radians(self.stop_deceleration_deg_s2), False)
        except RuntimeError as exc:
            raise ConnectionLost(f"stopJ: {exc}", device=self.device) from None
        self._wait_still()

    def _wait_still(self, frames: int = 3) -> None:
        """Until `frames` new RTDE frames in a row report the same joints (the arm stands), io_timeout_s at most."""
        deadline = time.monotonic() + self.io_timeout_s
        stamp, last, same = None, None, 0
        while same < frames:
            t, q, _ = self._sample()
            if t != stamp:
                stamp = t
                same = same + 1 if last is not None and _alike(q, last) else 0
                last = q
            if time.monotonic() > deadline:
                raise DeviceTimeout(f"the arm still moves {self.io_timeout_s:g} s after stopJ", device=self.device)
            time.sleep(POLL_S)

    def _brake_quietly(self) -> None:
        with contextlib.suppress(DeviceError):  # the error being raised says more than a failed stop on a lost link
            self._brake()

    def stop(self) -> None:
        """Brake the running move (stopJ, sent by the moving thread within POLL_S); returns once that move ended.
        A no-op when no move runs; DeviceTimeout if it did not end within io_timeout_s."""
        with self._lock:
            if not self._moving:
                return
            self._stop_asked = "stop requested"
            if not self._lock.wait_for(lambda: not self._moving, timeout=self.io_timeout_s):
                raise DeviceTimeout(f"the move did not stop within {self.io_timeout_s:g} s", device=self.device)

    def state(self) -> RobotState:
        """Moving while a move runs; the fault latched (a protective stop seen during a move) or active now."""
        with self._lock:
            moving, fault = self._moving, self._fault
        if not fault and self.receive is not None and self.receive.isConnected():
            fault = self._safety_text(self.safety_status_bits())
        return RobotState(moving=moving, fault=fault)

    def reset_faults(self) -> None:
        """After the operator acknowledged: unlock a protective stop through the dashboard (refused by the
        controller until 5 s after it occurred: retried for unlock_timeout_s), close the safety popup and the
        popup, and upload the control script again when it no longer runs. DeviceFault if a fault is still active
        (an emergency stop pressed, the robot not running)."""
        bits = self.safety_status_bits()
        if any(bits >> b & 1 for b in EMERGENCY_BITS):
            raise DeviceFault(
                f"{self._safety_text(bits)} still active: release it and reset on the teach pendant",
                code="emergency_stop",
                device=self.device,
            )
        if bits >> PROTECTIVE_STOP_BIT & 1:
            deadline = time.monotonic() + self.unlock_timeout_s
            while True:
                refused = ""
                try:
                    self._dash("unlockProtectiveStop")
                except ConnectionLost as exc:  # ur_rtde raises the controller's refusal as a RuntimeError
                    if "cannot unlock" not in str(exc).lower():
                        raise
                    refused = str(exc).split(": ", 2)[-1]
                if not refused and not self.protective_stopped():
                    break
                if time.monotonic() > deadline:
                    raise DeviceFault(
                        f"the protective stop could not be unlocked within {self.unlock_timeout_s:g} s"
                        + (f" ({refused})" if refused else ""),
                        code="protective_stop",
                        device=self.device,
                    )
                time.sleep(0.2)
            self._dash("closeSafetyPopup")
            self._dash("closePopup")
        self._require_running("fault reset")
        if self.control is None:  # connected while protective-stopped: the control script starts now
            self._start_control()
            with self._lock:
                self._fault = ""
            return
        try:
            if not self.control.isProgramRunning():
                if not self.control.reuploadScript():
                    raise DeviceFault(
                        "the control script could not be uploaded again", code="script", device=self.device
                    )
                deadline = time.monotonic() + self.io_timeout_s  # the upload returns before the script plays
                while not self.control.isProgramRunning():
                    if time.monotonic() > deadline:
                        raise DeviceFault(
                            f"the control script uploaded again is not running after {self.io_timeout_s:g} s",
                            code="script",
                            device=self.device,
                        )
                    time.sleep(POLL_S)
        except RuntimeError as exc:
            raise ConnectionLost(f"control script: {exc}", device=self.device) from None
        with self._lock:
            self._fault = ""

    def wait_settled(self, tolerance_deg: float, window_s: float, timeout_s: float) -> tuple[float, ...]:
        """Joints of frames arriving after the call that stay within tolerance_deg of the window's first frame
        for window_s of controller time (the RTDE timestamp); returns the last of them. The motion guard is polled
        every POLL_S: a reason ends the wait (DeviceFault code "stopped")."""
        require_settle_limits(tolerance_deg, window_s, timeout_s)
        real_deadline = time.monotonic() + timeout_s + self.stale_s
        start, _, _ = self._sample()
        stamp = start
        anchor: tuple[float, ...] | None = None
        anchor_t = 0.0
        while True:
            reason = self._guard()
            if reason:
                raise DeviceFault(f"settling stopped: {reason}", code=stop_code(reason), device=self.device)
            t, q, bits = self._sample()
            if bits >> PROTECTIVE_STOP_BIT & 1:
                with self._lock:
                    self._fault = self._safety_text(bits)
                raise DeviceFault(
                    f"settling ended by the robot: {self._fault}", code="protective_stop", device=self.device
                )
            if t != stamp:
                stamp = t
                deg = to_deg(q)
                if anchor is None or any(abs(a - b) > tolerance_deg for a, b in zip(deg, anchor, strict=True)):
                    anchor, anchor_t = deg, t
                if t - anchor_t >= window_s - 1e-9:
                    return deg
                if t - start > timeout_s:
                    raise DeviceTimeout(
                        f"joints not settled within {tolerance_deg} deg over {window_s} s after "
                        f"{timeout_s} s of controller time",
                        device=self.device,
                    )
            if time.monotonic() > real_deadline:
                raise DeviceTimeout(
                    f"RTDE frames stopped coming while waiting to settle ({timeout_s} s)", device=self.device
                )
            time.sleep(POLL_S)


def _shut(dev, control: bool) -> None:
    """Stop a control interface's script, then disconnect the interface: ur_rtde's destructor has nothing left to
    write."""
    with contextlib.suppress(RuntimeError):
        if control and dev.isConnected():
            dev.stopScript()
    with contextlib.suppress(RuntimeError):
        dev.disconnect()


def _bounded(call: Callable[[], None], timeout_s: float) -> bool:
    """Whether `call` returned within `timeout_s`, run in a daemon thread (ur_rtde's calls release the GIL). ur_rtde
    1.6.5's stopScript can wait forever once a stop has ended the script: tests/test_ur_safety.py hung in its
    teardown on a loaded machine, the door's stopJ sent; close() then gives up on that interface."""
    worker = threading.Thread(target=call, daemon=True, name="ur_rtde close")
    worker.start()
    worker.join(timeout_s)
    return not worker.is_alive()


def _connected(dev) -> bool:
    try:
        return bool(dev.isConnected())
    except RuntimeError:
        return False


def _alike(a_rad: Sequence[float], b_rad: Sequence[float]) -> bool:
    """Two frames' joints within the interface's resolution of each other (a standing arm; encoder noise of a real
    one stays below it)."""
    return max(abs(math.degrees(a - b)) for a, b in zip(a_rad, b_rad, strict=True)) < RESOLUTION_DEG


def to_deg(q_rad: Sequence[float]) -> tuple[float, ...]:
    """Joint angles in degrees at the Robot interface's 4 decimals."""
    return tuple(round(math.degrees(v), 4) + 0.0 for v in q_rad)
