"""KUKA KR C2 client (drivers.interfaces.Robot): EKI for motion, RSI 2.x as a joint monitor.

On the KR C2 both interfaces have the controller as the network *client*: trackcal listens on two ports and
the robot connects (drivers.kuka.peers: only the controller named in the hardware file is served). The programs
and configs the controller needs are in configs/krc2/ (see configs/krc2/README.md); the RSI defaults (protocol,
passive) are the shipped configs/krc2/trackcal_rsi.xml's. KukaKrc2 composes the two channels and keeps the motion:

- EKI (drivers.kuka.eki_link, TCP): one <RobotCommand> per request (drivers.kuka.eki_codec): a move, a stop of the
  running move, a reset of the fault flags; the KRL program (configs/krc2/trackcal_eki.src, after the KR C2 EKI
  program of ros-industrial/kuka_experimental pull request #205) answers moves and resets with one <RobotState>.
  The echoed ID is the acknowledgement; Error != 0 -> DeviceFault (its code).
- RSI (drivers.kuka.rsi_link, UDP by default, as on a KR C2; TCP available): the answering and monitor threads, the
  latest joints and their freshness, the lockstep with a simulated controller (`rsi_sync`, see there).
- A move is refused when the RSI stream is stale: no complete frame for more than STALE_CYCLES cycles; the
  client waits at most rsi_stale_s for a fresh one before it refuses, and never sends the move.
- `motion_guard` (a callable returning None, or why the robot must stop) is polled at least every GUARD_S
  (25 Hz) during every move and settle: during a move it makes the client send the stop request (Kind 2: the KRL
  brakes) and the move end in DeviceFault; during settling it ends the wait the same way. The fault's code names
  the cause: the StopCause's code the guard gave (drivers.interfaces: the door, a silent PLC ...), RSI_STALE when
  the RSI stream went silent for more than rsi_stale_s during the move or the settle (checked by the client
  itself, beside the guard), else the controller's ERR_STOPPED (a plain reason, or `stop()`).
  `stop()`, from another thread than the one moving, does the same for the running move and returns once the
  controller answered it (the arm stands).
- `state()` is what the client already knows, without wire traffic: moving while a move it sent is unanswered;
  the fault latched by the controller (E-stop seen, drives off, RSI stop: Error 1, 2, 4) as the last answer
  reported it. The KRL program reports only in answers (trackcal_eki.src), so a fault that arrives while the arm
  stands shows in the answer to the next request.
- Two channels, one arm (issue 27): the answer to a move carries $AXIS_ACT at the end of the program's dwell (EKI),
  the settled joints come from RSI. `wait_settled` checks that they agree within the settle tolerance plus one
  count (JOINT_RESOLUTION_DEG: the arm moved less than the tolerance over the window, and each channel rounds to a
  count); otherwise DeviceFault CHANNELS_DISAGREE naming the joint and both values: the RSI stream is not this
  arm's (a spoofer followed before the controller's session began), or a channel lies. The engine then compares
  the settled joints with the target.
- Settling (`wait_settled`) is judged on RSI frames in controller time: one frame = one interpolation cycle of
  rsi_cycle_s (12 ms on a KR C2, 4 ms on a KR C4: the hardware file says which). The same code is then right for
  the real robot and for the mock controller on a virtual clock. A real-time guard (timeout_s + rsi_stale_s)
  still bounds the wait if frames stop coming.

Targets are checked before anything is sent (joint limits, then the optional cell-box callable):
MotionRefused.
"""

from __future__ import annotations

import itertools
import math
import threading
import time
from collections.abc import Callable, Sequence

from trackcal.drivers.errors import ConnectionLost, DeviceFault, DeviceTimeout, ProtocolError
from trackcal.drivers.interfaces import FROM_HARDWARE_FILE, JOINT_RESOLUTION_DEG, DeviceIdentity, RobotState, StopCause
from trackcal.drivers.kuka.eki_codec import (
    AXES,
    ERR_DRIVES_OFF,
    ERR_ESTOP,
    ERR_RSI_STOPPED,
    ERR_STOPPED,
    ERROR_TEXT,
    KIND_MOVE,
    KIND_RESET,
    KIND_STOP,
    MAX_ID,
    Command,
)
from trackcal.drivers.kuka.eki_codec import RobotState as EkiState
from trackcal.drivers.kuka.eki_link import EkiLink
from trackcal.drivers.kuka.peers import ControllerPeers
from trackcal.drivers.kuka.rsi_codec import KRC2_CYCLE_S, SHIPPED
from trackcal.drivers.kuka.rsi_link import POLL_S, RSI_STALE, RsiLink, RsiSync
from trackcal.drivers.motion_request import checked_limits, checked_speed, checked_target
from trackcal.drivers.transport import SettleWindow, require_positive, require_settle_limits

GUARD_S = 0.04  # the motion guard is polled at least this often during moves and settling (25 Hz >= 20 Hz)
# the faults the KRL program latches until a reset finds them gone (trackcal_eki.src); other errors refuse one request
LATCHED = (ERR_ESTOP, ERR_DRIVES_OFF, ERR_RSI_STOPPED)
# stop codes of this client's own causes (the guard's come with its StopCause; RSI_STALE: drivers.kuka.rsi_link)
CHANNELS_DISAGREE = "channels_disagree"  # EKI's answer and RSI's settled frame do not show the same arm

CellBoxCheck = Callable[[tuple[float, ...]], "str | None"]
MotionGuard = Callable[[], "str | None"]


# the controller's identity when the hardware file states none (KukaKrc2.identity)
UNSTATED = DeviceIdentity(model="KUKA KR C2", source=FROM_HARDWARE_FILE)


class KukaKrc2:
    """A KUKA KR C2 with the trackcal KRL program (EKI) and the RSI monitor running."""

    def __init__(
        self,
        eki_host: str,
        eki_port: int,
        rsi_host: str,
        rsi_port: int,
        rsi_protocol: str = SHIPPED.protocol,
        *,
        controller_host: str,
        rsi_passive: bool = SHIPPED.passive,
        rsi_cycle_s: float = KRC2_CYCLE_S,
        joint_limits_deg: Sequence[tuple[float, float]] = ((-180.0, 180.0),) * 6,
        cell_box_check: CellBoxCheck | None = None,
        motion_guard: MotionGuard | None = None,
        connect_timeout_s: float = 60.0,
        move_timeout_s: float = 300.0,
        io_timeout_s: float = 5.0,
        rsi_stale_s: float = 1.0,
        rsi_sync: RsiSync | None = None,
        identity: DeviceIdentity = UNSTATED,
    ) -> None:
        if rsi_protocol not in ("tcp", "udp"):
            raise ValueError(f"rsi_protocol must be 'tcp' or 'udp', got {rsi_protocol!r}")
        require_positive(
            connect_timeout_s=connect_timeout_s,
            move_timeout_s=move_timeout_s,
            io_timeout_s=io_timeout_s,
            rsi_stale_s=rsi_stale_s,
            rsi_cycle_s=rsi_cycle_s,
        )
        limits = checked_limits(joint_limits_deg, AXES)
        self.controller_host = controller_host
        self.stated_identity = identity
        self.joint_limits_deg = limits
        self.cell_box_check = cell_box_check
        self.motion_guard = motion_guard
        self.connect_timeout_s = connect_timeout_s
        self.move_timeout_s = move_timeout_s
        self.io_timeout_s = io_timeout_s
        mode = "passive" if rsi_passive else "answered"
        self.device = f"KR C2 eki {eki_host}:{eki_port} rsi {rsi_protocol} {mode} {rsi_host}:{rsi_port}"
        self._peers = ControllerPeers(controller_host, self.device)
        self.eki = EkiLink(eki_host, eki_port, self._peers, io_timeout_s=io_timeout_s)
        self.rsi = RsiLink(
            rsi_host,
            rsi_port,
            rsi_protocol,
            self._peers,
            passive=rsi_passive,
            cycle_s=rsi_cycle_s,
            stale_s=rsi_stale_s,
            sync=rsi_sync,
        )
        self._ids = itertools.count(1)
        self._motion = threading.Condition()  # guards the three below, between the moving thread and stop()/state()
        self._moving: int | None = None  # the ID of the move sent and not answered yet
        self._stop_asked: str | None = None  # why stop() asked to brake it
        self._ended: tuple[int, bool] = (0, True)  # the last move's ID, and whether the controller answered it
        self._fault = ""  # the latched fault the last answer reported ("" when none)
        self._answered: tuple[int, tuple[float, ...]] | None = None  # the last move done: its ID, EKI's joints

    @property
    def refused_peers(self) -> list[tuple[str, int]]:
        """(address, port) of every connection and datagram refused: not from the controller."""
        return self._peers.refused

    # --- connection -----------------------------------------------------------------------------------------

    def listen(self) -> None:
        """Open both listening ports (port 0 picks a free one; see eki.address / rsi.address). Idempotent."""
        self.eki.listen()
        self.rsi.listen()

    def connect(self) -> None:
        """Listen; accept the controller's EKI connection and first RSI frame within connect_timeout_s."""
        if self.eki.connected:
            return
        self.listen()
        deadline = time.monotonic() + self.connect_timeout_s
        try:
            self.eki.accept(deadline, self.connect_timeout_s)
            self.rsi.accept(deadline, self.connect_timeout_s)
        except BaseException:
            self.close()
            raise
        self.rsi.start()

    def _require_connected(self) -> None:
        if not (self.eki.connected and self.rsi.connected):
            raise ConnectionLost("not connected (call connect() first)", device=self.device)

    def identity(self) -> DeviceIdentity:
        """The controller's identity as the hardware file states it: neither channel can ask it. EKI exchanges only
        the XML a KRL program of the cell writes and reads (KUKA, "KUKA.EthernetKRL 2.1/3.0" manuals: a channel is the
        elements of its own configuration file, configs/krc2/TrackcalEki.xml), and RSI's telegram carries only the
        objects its configuration sends (configs/krc2/trackcal_rsi.xml: AIPos, Delay ...). The serial number and
        model are system variables ($KR_SERIALNO, $MODEL_NAME[]) that other channels read (CrossComm's ShowVar behind
        KukaVarProxy, the KR C4's OPC UA server, as public clients do), which trackcal does not open, and that
        trackcal_eki.src does not send."""
        return self.stated_identity

    def close(self) -> None:
        self.rsi.close()
        self.eki.close()

    def __enter__(self) -> KukaKrc2:
        self.connect()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # --- Robot protocol -------------------------------------------------------------------------------------

    def joints(self) -> tuple[float, ...]:
        self._require_connected()
        return self.rsi.joints()

    def check_target(self, target_deg: Sequence[float]) -> tuple[float, ...]:
        """The target as a tuple, or MotionRefused (joint limits first, then the cell box)."""
        return checked_target(target_deg, AXES, self.joint_limits_deg, self.cell_box_check, self.device)

    def move(self, target_deg: tuple[float, ...], speed_override_pct: float) -> None:
        target = self.check_target(target_deg)
        speed = checked_speed(speed_override_pct, self.device)
        self._require_connected()
        self.rsi.require_fresh()  # never move without the monitor
        command_id = self._next_id()
        with self._motion:
            self._moving, self._stop_asked, self._answered = command_id, None, None
        stood = False
        try:
            self.eki.send(Command(command_id, KIND_MOVE, target, int(round(speed))))
            state, stopped = self._await_state(command_id, guarded=True)
            stood = True  # the controller answered: the move is over, the arm stands
        finally:
            with self._motion:
                self._moving, self._ended = None, (command_id, stood)
                self._motion.notify_all()
        if stopped:
            raise DeviceFault(
                f"move {command_id} to {target} stopped: {stopped}",
                code=getattr(stopped, "code", ERR_STOPPED),
                device=self.device,
            )
        if state.error:
            text = ERROR_TEXT.get(state.error, "controller fault")
            raise DeviceFault(f"move {command_id} to {target} failed: {text}", code=state.error, device=self.device)
        if not state.done:
            raise ProtocolError(
                f"move {command_id} acknowledged without Done and without an error code", device=self.device
            )
        self._answered = (command_id, state.joints_deg)

    def reset_faults(self) -> None:
        """Clear the controller's fault flags (after the operator acknowledged); DeviceFault if one is still
        active (e.g. the emergency stop not released)."""
        self._require_connected()
        command_id = self._next_id()
        self.eki.send(Command(command_id, KIND_RESET))
        state, _ = self._await_state(command_id, guarded=False)
        if state.error:
            text = ERROR_TEXT.get(state.error, "controller fault")
            raise DeviceFault(f"fault reset {command_id}: {text} still active", code=state.error, device=self.device)

    def stop(self) -> None:
        """Brake the running move: the stop request (Kind 2) for it, sent by the moving thread within GUARD_S; the
        KRL brakes and answers the move with Error 6, which ends move() in DeviceFault code ERR_STOPPED. Returns
        once the controller answered the move (the arm stands); DeviceTimeout if the move ended without an
        answer (the arm may still move). A no-op when no move runs."""
        bound = GUARD_S + 2 * self.io_timeout_s  # noticed, the stop request sent, its answer awaited
        with self._motion:
            command_id = self._moving
            if command_id is None:
                return
            self._stop_asked = "stop requested"
            ended = self._motion.wait_for(lambda: self._moving != command_id, timeout=bound)
            answered = self._ended == (command_id, True)
        if not ended or not answered:
            raise DeviceTimeout(
                f"move {command_id} not stopped within {bound} s: no answer from the controller", device=self.device
            )

    def state(self) -> RobotState:
        """Moving while a move sent is unanswered; the fault the controller latched, as its last answer said."""
        with self._motion:
            return RobotState(moving=self._moving is not None, fault=self._fault)

    def _next_id(self) -> int:
        return next(self._ids) % MAX_ID or next(self._ids)

    def _guard(self) -> str | None:
        reason = self._cause()
        if reason:
            return reason
        with self._motion:
            return self._stop_asked

    def _cause(self) -> str | None:
        """Why the robot must stop now: the motion guard's reason, or the RSI stream silent for too long."""
        if self.motion_guard is not None:
            reason = self.motion_guard()
            if reason:
                return reason
        silent = self.rsi.stale_for()
        if silent is not None:
            return StopCause(
                f"the RSI stream went stale: no frame for {silent:.1f} s (rsi_stale_s "
                f"{self.rsi.stale_s:g} s); check the controller's RSI program and its network to this "
                "PC",
                RSI_STALE,
            )
        return None

    def _await_state(self, command_id: int, guarded: bool) -> tuple[EkiState, str | None]:
        """The controller's answer to `command_id`, and why it was stopped (None if it was not). While
        `guarded`, the motion guard (and stop()) is polled every GUARD_S; when it names a reason the stop request is
        sent and the answer awaited io_timeout_s more (the robot brakes)."""
        deadline = time.monotonic() + self.move_timeout_s
        stopped: str | None = None
        next_guard = time.monotonic()
        while True:
            now = time.monotonic()
            if guarded and stopped is None and now >= next_guard:
                stopped = self._guard()
                next_guard = now + GUARD_S
                if stopped:
                    self.eki.send(Command(command_id, KIND_STOP))
                    deadline = time.monotonic() + self.io_timeout_s
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                what = "stop" if stopped else "request"
                raise DeviceTimeout(
                    f"{what} {command_id} not acknowledged within "
                    f"{self.io_timeout_s if stopped else self.move_timeout_s} s",
                    device=self.device,
                )
            state = self.eki.receive_state(command_id, min(remaining, GUARD_S if guarded else POLL_S * 4))
            if state is not None:
                with self._motion:
                    self._fault = ERROR_TEXT[state.error] if state.error in LATCHED else ""
                return state, stopped

    def wait_settled(self, tolerance_deg: float, window_s: float, timeout_s: float) -> tuple[float, ...]:
        """Joints from RSI frames arriving after the call that stay within tolerance_deg of the window's first
        frame for window_s of controller time; returns the last of them. The motion guard is polled every
        GUARD_S, and the RSI stream's freshness: a reason ends the wait (DeviceFault, the cause's code). The settled
        joints must agree with EKI's answer to the last move (DeviceFault CHANNELS_DISAGREE otherwise)."""
        require_settle_limits(tolerance_deg, window_s, timeout_s)
        self._require_connected()
        rsi = self.rsi
        cycle = rsi.cycle_s
        real_deadline = time.monotonic() + timeout_s + rsi.stale_s
        if rsi.sync is not None:  # simulation: every frame due before the call is in
            rsi.sync(0)
        next_seq = rsi.last_seq + 1
        window = SettleWindow(tolerance_deg, window_s, timeout_s, cycle, next_seq, self.device)
        next_guard = time.monotonic()
        while True:
            if time.monotonic() >= next_guard:
                reason = self._cause()
                if reason:
                    raise DeviceFault(
                        f"settling stopped: {reason}", code=getattr(reason, "code", ERR_STOPPED), device=self.device
                    )
                next_guard = time.monotonic() + GUARD_S
            first_seq, frames = rsi.frames_from(next_seq)
            if next_seq < first_seq:  # fell behind the history: restart the window
                next_seq = first_seq
                window.restart()
            for seq, joints in frames:
                next_seq = seq + 1
                if window.settled(seq, joints):
                    self._check_channels(joints, tolerance_deg)
                    return joints
            remaining = real_deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeout(
                    f"RSI frames stopped coming while waiting to settle ({timeout_s} s)",
                    device=self.device,
                )
            if rsi.sync is None:
                rsi.wait_for_frame(next_seq, min(remaining, GUARD_S))
                continue
            # simulation: the cycles the window still needs, GUARD_S of controller time at most per request
            rsi.sync(max(1, min(window.frames_wanted(next_seq), math.ceil(GUARD_S / cycle))))

    def _check_channels(self, settled: tuple[float, ...], tolerance_deg: float) -> None:
        """RSI's settled joints against EKI's answer to the last move done (none since: nothing to compare)."""
        if self._answered is None:
            return
        command_id, answered = self._answered
        allowed = tolerance_deg + JOINT_RESOLUTION_DEG
        for name, rsi, eki in zip(AXES, settled, answered, strict=True):
            if abs(rsi - eki) > allowed + 1e-9:
                raise DeviceFault(
                    f"after move {command_id} the two channels disagree on {name}: RSI {rsi:.4f} deg, EKI "
                    f"{eki:.4f} deg (more than {allowed:g} deg apart, the settle tolerance and one count): the RSI "
                    "stream may not be this arm's (another sender on the controller's address?)",
                    code=CHANNELS_DISAGREE,
                    device=self.device,
                )
