"""Deterministic mock of a KUKA KR C2 running configs/krc2 (trackcal_eki.src + the RSI monitor).

Like the real controller it is the network *client*: it connects to the EKI (and, over TCP, the RSI) port where
trackcal listens, retrying (the first time bounded by connect_timeout_s of wall time) until they are up. Then one
thread runs the controller until stop():

    every interpolation cycle (cycle_s, 12 ms on a KR C2; on the injected clock, advanced with clock.sleep):
      read the EKI requests that arrived (FIFO, like the EKX buffer), step the motion, send one RSI <Rob> and,
      unless passive (ONLYSEND TRUE), wait for the <Sen> answer with the same IPOC; an answer that misses the
      budget is late, and more than max_late_packages late answers in a row stop the robot (RSI error) as
      eERXmaxLatePackages does.

When trackcal disconnects (EKI end of stream) the controller keeps its state and its RSI stream, and connects
again, as trackcal_eki.src closes and reopens its channel: a restarted trackcal finds it (`connections` counts).

Requests (drivers.kuka.eki_codec, element names from configs/krc2 through it): Kind 1 moves, answered when done;
Kind 2 stops the running move with that ID: the axes decelerate at brake_deg_s2 (all at the same rate relative
to their speed, so they stop together, as a synchronous PTP) and the move is answered with Error 6; a stop for
any other ID is ignored, as the KRL ignores it. Kind 3 resets the latched faults (E-stop, drives off), not an
RSI stop. `stops` records (joints, axis speeds, joints at standstill) for every braking.

Motion: mocks/servers/kuka/motion.py (a synchronous PTP with a quintic profile, a decaying residual oscillation
after arrival, the dwell of settle_s, then $AXIS_ACT (4 decimals) in <RobotState>; braking). Everything is computed
from integer cycle counts and one random.Random(seed), so the same seed and the same commands give the same bytes;
only how many idle cycles run between commands depends on the wall-clock pace of the peer. The socket ends are
mocks/servers/kuka/links.py.

The answer budget is wall time (answer_budget_s, default 0.25 s): the real controller allows ~10 ms, which a
loaded CI machine running Python cannot promise; tests that need lateness set a small budget and a slow
client. In passive mode no answer paces the controller: on a virtual clock it leaves PASSIVE_PACE_S of wall
time between cycles.

Lockstep (`delivered` given: `run --sim`, where trackcal's client runs in the same process on the same virtual
clock). Cycle n is due at virtual time t0 + n * cycle_s and its frame carries IPOC ipoc0 + n * cycle in ms (the
IPOC counts milliseconds of controller time: kuka_rsi_simulator adds the cycle time in ms to it every cycle, ros-
industrial/kuka_experimental kuka_rsi_simulator/scripts/kuka_rsi_simulator). The controller runs at most
LOCKSTEP_AHEAD frames ahead of what the client received (no wall pacing, no datagram lost). While the robot moves
(or brakes, dwells, oscillates) the controller runs every cycle and advances the clock to it, as before. While it
stands still with nothing queued it does not advance the clock: it follows it. Cycles the clock passes (the tracker
measuring, the operator walking) are all exchanged, or with skip_idle (the default) skipped: the next frame sent
carries the IPOC of its own cycle, so the client sees controller time jump, and a standing robot's frames carry
nothing else that changes. The client asks for what it reads while the robot stands (`sync`: the current frame, or
n more cycles for its settling window); whoever waits for time advances it, so the clock, and with it every
timestamp of the session, is a pure function of the commands, the same with and without skipping. EKI requests,
injected faults and stops are served at once in both modes (the controller wakes on them).

Fault injection: estop(), drives_off() (reported as RobotState Error 1/2, see drivers.kuka.eki_codec), a
target outside soft_limits_deg (Error 3), RSI stop after late answers (Error 4), drop_connection("eki"|"rsi"),
send_garbage("eki"|"rsi"), lose_rsi() (every RSI frame lost on the wire from now: the controller, passive, does
not notice; the stream goes stale at trackcal) and misreport("eki"|"rsi", axis, offset_deg) (that channel reports
one joint off by offset_deg: the two channels disagree). Garbage from the peer never raises out of the thread: it
is recorded in `errors` and the connection it came on is dropped (a stream cannot be resynchronised).
"""

from __future__ import annotations

import contextlib
import math
import random
import select
import socket
import threading
from collections import deque
from collections.abc import Callable, Sequence

from trackcal.drivers.errors import ProtocolError
from trackcal.drivers.interfaces import RealClock
from trackcal.drivers.kuka.eki_codec import (
    AXES,
    ERR_BAD_COMMAND,
    ERR_DRIVES_OFF,
    ERR_ESTOP,
    ERR_RSI_STOPPED,
    ERR_SOFT_LIMIT,
    KIND_MOVE,
    KIND_RESET,
    KIND_STOP,
    Command,
    RobotState,
    command_id_of,
    encode_state,
    parse_command,
)
from trackcal.drivers.kuka.rsi_codec import CART, KRC2_CYCLE_S, SHIPPED, RobFrame, encode_rob
from trackcal.mocks.servers.kuka.links import EkiEnd, RsiEnd
from trackcal.mocks.servers.kuka.motion import Motion, Stop

DEFAULT_SOFT_LIMITS_DEG = (
    (-185.0, 185.0),
    (-146.0, 0.0),
    (-119.0, 155.0),
    (-350.0, 350.0),
    (-125.0, 125.0),
    (-350.0, 350.0),
)
_QUEUE_LIMIT = 16
_RECONNECT_S = 0.05  # wall time between connection attempts while trackcal is away
# A passive controller waits for no answer, so on a virtual clock nothing would pace it: it leaves at least this
# much wall time between cycles (2000 frames/s at most, 24x real time at 12 ms), or it would flood the receiver.
PASSIVE_PACE_S = 0.0005
# Lockstep: a standing controller looks at the clock at least this often (wall time) when nothing wakes it.
IDLE_WAKE_S = 0.05
# Lockstep: how long (wall time) a sync request or a frame's delivery may take before it counts as lost.
LOCKSTEP_TIMEOUT_S = 2.0
# Lockstep: frames the controller may be ahead of the client (~30 KB of the receiver's UDP buffer, >= 200 KB on
# Linux); waiting for each one would cost a thread switch per cycle on a loaded machine. Past it the controller
# waits until the client has every frame sent, then sends up to this many more.
LOCKSTEP_AHEAD = 64
# Free-running: how many cycles late the controller still catches up by running them at once (25 cycles: 100 ms at
# 4 ms, 0.3 s at 12 ms); later than that it starts a new schedule (_pace).
CATCH_UP_CYCLES = 25
_NO_POSE = (0.0,) * len(CART)  # RIst and RSol: the mock computes no Cartesian pose


def _checked_start(rsi_protocol: str, initial_joints_deg: Sequence[float], cycle_s: float, brake_deg_s2: float):
    """The controller's start joints (deg), its arguments checked (ValueError)."""
    if rsi_protocol not in ("tcp", "udp"):
        raise ValueError("rsi_protocol must be 'tcp' or 'udp'")
    q0 = tuple(float(v) for v in initial_joints_deg)
    if len(q0) != len(AXES):
        raise ValueError(f"initial_joints_deg needs {len(AXES)} values")
    if not (cycle_s > 0 and brake_deg_s2 > 0):
        raise ValueError("cycle_s and brake_deg_s2 must be positive")
    return q0


class MockKrc2:
    def __init__(
        self,
        eki_addr: tuple[str, int],
        rsi_addr: tuple[str, int],
        clock,
        initial_joints_deg: Sequence[float],
        joint_speed_deg_s: float = 60.0,
        settle_s: float = 0.5,
        on_joints: Callable[[tuple[float, ...]], None] | None = None,
        seed: int = 0,
        rsi_protocol: str = SHIPPED.protocol,
        rsi_passive: bool = SHIPPED.passive,
        cycle_s: float = KRC2_CYCLE_S,
        soft_limits_deg: Sequence[tuple[float, float]] = DEFAULT_SOFT_LIMITS_DEG,
        max_late_packages: int = 10,
        answer_budget_s: float = 0.25,
        connect_timeout_s: float = 10.0,
        overshoot_deg: float = 0.02,
        brake_deg_s2: float = 200.0,
        wall_clock=None,
        delivered: Callable[[int, float], bool] | None = None,
        skip_idle: bool = True,
    ) -> None:
        q0 = _checked_start(rsi_protocol, initial_joints_deg, cycle_s, brake_deg_s2)
        self.sen_type = SHIPPED.sen_type
        self.eki_addr, self.rsi_addr = eki_addr, rsi_addr
        self.clock = clock
        self.wall = wall_clock or RealClock()  # network waits are real; the controller's own time is `clock`
        self.on_joints = on_joints
        self.rsi_protocol = rsi_protocol
        self.rsi_passive = bool(rsi_passive)
        self.cycle_s = float(cycle_s)
        self.soft_limits_deg = tuple((float(lo), float(hi)) for lo, hi in soft_limits_deg)
        self.max_late_packages = int(max_late_packages)
        self.answer_budget_s = float(answer_budget_s)
        self.connect_timeout_s = float(connect_timeout_s)
        self._rng = random.Random(seed)
        self._ipoc_step = max(1, round(self.cycle_s * 1000))  # IPOC counts milliseconds (kuka_rsi_simulator)
        self._ipoc0 = self._ipoc_step * self._rng.randrange(10**6, 10**7)
        self._delivered = delivered  # lockstep with a client on the same virtual clock (see the module docstring)
        self.skip_idle = bool(skip_idle)
        self._tick = 0  # index of the next cycle; its frame carries IPOC _ipoc0 + _ipoc_step * _tick
        self._t0 = clock.now()  # lockstep: cycle n is due at _t0 + n * cycle_s (from the integer, never summed)
        self._syncs: list[list] = []  # [cycles still to run, threading.Event, answer list] (lockstep)
        self._ipoc_sent: int | None = None  # IPOC of the last frame sent, and of the last known received
        self._ipoc_received: int | None = None
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)

        self.errors: list[str] = []
        self.motion = Motion(
            q0,
            self._rng,
            joint_speed_deg_s=joint_speed_deg_s,
            settle_s=settle_s,
            cycle_s=self.cycle_s,
            overshoot_deg=overshoot_deg,
            brake_deg_s2=brake_deg_s2,
        )
        self._queue: deque[Command] = deque()
        self._fault = 0
        self._last_reported: tuple[float, ...] | None = None
        self._misreport: dict[str, tuple[int, float]] = {}  # channel -> (axis index, offset_deg) (fault injection)
        self._wire_loses_rsi = False

        self._lock = threading.Lock()
        self._pending: list[tuple[str, object]] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._eki = EkiEnd(eki_addr, self.errors)
        self._rsi = RsiEnd(rsi_addr, rsi_protocol, self.sen_type, self.errors, self._rsi_lost)
        self._next_attempt = 0.0
        self._last_cycle = 0.0  # wall time of the last cycle's end (passive pacing)
        self._due: float | None = None  # free-running: the wall time the next cycle is due (_pace)
        self._init_observables()

    def _init_observables(self) -> None:
        """The state tests and people watch (counters, what was received and sent, how it ended)."""
        self.cycles = 0
        self.frames_sent = 0  # RSI frames sent
        self.idle_skipped = 0  # lockstep with skip_idle: cycles the robot stood through, not exchanged
        self.overruns = 0  # free-running: cycles that started more than a period after their deadline (_pace)
        self.late_packets = 0
        self.consecutive_late = 0
        self.rsi_stopped = False
        self.commands: list[Command] = []
        self.eki_sent: list[bytes] = []
        self.crashed: BaseException | None = None
        self.connected = threading.Event()
        self.connections = 0

    # --- control --------------------------------------------------------------------------------------------

    def start(self) -> MockKrc2:
        self._thread = threading.Thread(target=self._run, name="mock-krc2", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=self.answer_budget_s + 2.0)
        self._close("eki", None)
        self._close("rsi", None)
        for sock in (self._wake_r, self._wake_w):
            sock.close()

    def join(self, timeout: float) -> bool:
        """Wait (wall time) for the controller thread to end; True if it did."""
        if self._thread is not None:
            self._thread.join(timeout)
            return not self._thread.is_alive()
        return True

    @property
    def joints_deg(self) -> tuple[float, ...]:
        return self.motion.joints_deg

    @property
    def moving(self) -> bool:
        return self.motion.moving

    @property
    def joint_speed_deg_s(self) -> float:
        return self.motion.joint_speed_deg_s

    @property
    def settle_s(self) -> float:
        return self.motion.settle_s

    @property
    def overshoot_deg(self) -> float:
        return self.motion.overshoot_deg

    @property
    def brake_deg_s2(self) -> float:
        return self.motion.brake_deg_s2

    @property
    def stops(self) -> list[Stop]:
        """(joints, axis speeds, joints at standstill) for every braking."""
        return self.motion.stops

    # --- fault injection (any thread) -----------------------------------------------------------------------

    def estop(self) -> None:
        self._inject("fault", ERR_ESTOP)

    def drives_off(self) -> None:
        self._inject("fault", ERR_DRIVES_OFF)

    def drop_connection(self, channel: str = "eki") -> None:
        self._inject("drop", channel)

    def send_garbage(self, channel: str = "rsi", data: bytes = b'<Rob TYPE="KUKA"><AIPos A1=\x00\xff garbage') -> None:
        self._inject("garbage", (channel, data))

    def lose_rsi(self, lost: bool = True) -> None:
        """From now (until lose_rsi(False)) every RSI frame is lost on the wire: trackcal receives none."""
        self._inject("lose_rsi", lost)

    def misreport(self, channel: str, axis: int, offset_deg: float) -> None:
        """From now the channel ("eki": the RobotState answers, "rsi": the <Rob> AIPos) reports joint `axis` (0-5)
        offset_deg away from the arm's; offset 0 ends it."""
        if channel not in ("eki", "rsi") or not 0 <= axis < len(AXES):
            raise ValueError("misreport needs channel 'eki' or 'rsi' and an axis 0..5")
        self._inject("misreport", (channel, axis, float(offset_deg)))

    def _reported(self, channel: str) -> tuple[float, ...]:
        """The joints as `channel` reports them (4 decimals; misreport's offset added)."""
        q = self.joints_deg
        if channel in self._misreport:
            axis, offset = self._misreport[channel]
            q = tuple(round(v + offset, 4) if i == axis else v for i, v in enumerate(q))
        return q

    def _inject(self, what: str, arg: object) -> None:
        with self._lock:
            self._pending.append((what, arg))
        self._wake()

    def _wake(self) -> None:
        with contextlib.suppress(OSError):  # full (it is already awake) or closed (stopped)
            self._wake_w.send(b"w")

    # --- lockstep (any thread) ------------------------------------------------------------------------------

    def sync(self, cycles: int = 0) -> int | None:
        """Lockstep only (the client's rsi_sync hook): send the frames due on the clock (every one, or with
        skip_idle the current one), then run `cycles` more cycles; returns the IPOC of the last cycle (its frame
        received by the client, unless the stream is down), None if the controller did not answer within
        LOCKSTEP_TIMEOUT_S (plus the real time the cycles take on a paced clock, --sim-speed)."""
        if self._delivered is None:
            raise RuntimeError("sync needs a lockstep controller (delivered given)")
        request: list = [int(cycles), threading.Event(), []]
        with self._lock:
            self._syncs.append(request)
        self._wake()
        if not request[1].wait(LOCKSTEP_TIMEOUT_S + cycles * self.cycle_s * self.clock.real_fraction):
            return None
        return request[2][0]

    # --- thread ---------------------------------------------------------------------------------------------

    def _run(self) -> None:
        try:
            if not self._connect_first():
                return
            while not self._stop.is_set():
                self._cycle()
        except BaseException as exc:  # a mock must never die silently: tests assert crashed is None
            self.crashed = exc
            self.errors.append(f"mock crashed: {exc!r}")
        finally:
            self._close("eki", None)
            self._close("rsi", None)

    def _connect_first(self) -> bool:
        deadline = self.wall.now() + self.connect_timeout_s
        last: OSError | None = None
        while not self._stop.is_set() and self.wall.now() < deadline:
            last = self._reconnect()
            if self._eki.connected and (self._rsi.connected or self.rsi_protocol == "udp"):
                if not self._rsi.connected:
                    self._rsi.open_udp()
                return True
            self.wall.sleep(0.02)
        self.errors.append(f"could not connect to trackcal within {self.connect_timeout_s} s ({last})")
        return False

    def _reconnect(self) -> OSError | None:
        """One attempt at each missing connection (EKI; RSI over TCP); the last failure, if any."""
        failure = None
        if not self._eki.connected:
            failure = self._eki.connect()
            if failure is None:
                self.connections += 1
                self.connected.set()
        if not self._rsi.connected and self.rsi_protocol == "tcp":
            failure = self._rsi.connect_tcp() or failure
        return failure

    def _cycle(self) -> None:
        self._apply_injections()
        if not self._eki.connected or (not self._rsi.connected and self.rsi_protocol == "tcp" and not self.rsi_stopped):
            now = self.wall.now()
            if now >= self._next_attempt:  # trackcal is away: EKX_Open again, as trackcal_eki.src does
                self._next_attempt = now + _RECONNECT_S
                self._reconnect()
            if not self._eki.connected:
                self.wall.sleep(self.cycle_s)  # nobody to serve: do not spin through virtual time
        if self._delivered is not None and self._standing_still() and not self._work_arrived():
            return
        self._poll_eki(0.0 if self._rsi.connected else self.cycle_s)
        if self._delivered is not None:  # the cycle's time: advance the clock to it unless it is already there
            self.clock.sleep(self._t0 + self._tick * self.cycle_s - self.clock.now())
        self._step()
        q = self.joints_deg
        if self.on_joints is not None and q != self._last_reported:
            self._last_reported = q
            self.on_joints(q)
        if self._rsi.connected:
            self._rsi_exchange()
        self._tick += 1
        if self._delivered is None:
            self._pace()
            if self.rsi_passive:
                rest = self._last_cycle + PASSIVE_PACE_S - self.wall.now()
                if rest > 0:
                    self.wall.sleep(rest)
                self._last_cycle = self.wall.now()
        else:
            self._answer_syncs(ran_cycle=True)
        self.cycles += 1

    def _pace(self) -> None:
        """Free-running: one cycle of the controller's time, and the wall time to the next cycle's deadline on a
        fixed schedule (a cycle's work, the exchange and the wait for its answer, is inside its period instead of
        added to it: sleeping a whole cycle after the work gave 186 frames/s at 4 ms, docs/krc4.md). A virtual
        clock's real_fraction scales the period (0: no wall pacing), a real clock is paced at 1. A cycle begun more
        than a period late is an overrun (counted); the late cycles catch up at once, up to CATCH_UP_CYCLES behind,
        past which the schedule starts again from now (a stall is not followed by a long burst of frames)."""
        advance = getattr(self.clock, "advance", None)
        if advance is None:  # a real clock: its time is the wall's
            fraction = 1.0
        else:
            advance(self.cycle_s)
            fraction = self.clock.real_fraction
        if fraction <= 0:
            return
        period, now = self.cycle_s * fraction, self.wall.now()
        self._due = now + period if self._due is None else self._due + period
        if self._due > now:
            self.wall.sleep(self._due - now)
        elif now - self._due > period:
            self.overruns += 1
            if now - self._due > CATCH_UP_CYCLES * period:
                self._due = now

    # --- lockstep (the controller thread) -------------------------------------------------------------------

    def _standing_still(self) -> bool:
        return self.motion.still and not self._queue

    def _work_arrived(self) -> bool:
        """A standing controller in lockstep: wait (wall, at most IDLE_WAKE_S) for an EKI request, an injection or
        a sync, follow the clock, answer what needs no cycle; True when a cycle must run (a request queued, a sync
        that wants cycles). Injections come first: with one pending nothing else is done before the next call of
        _cycle applies it (without running a cycle)."""
        with self._lock:
            if self._pending:
                return False
            busy = bool(self._syncs)
        if not busy:
            eki = self._eki.sock
            socks = [self._wake_r] + ([eki] if eki is not None else [])
            readable, _, _ = select.select(socks, [], [], IDLE_WAKE_S)
            if self._wake_r in readable:
                with contextlib.suppress(OSError):
                    self._wake_r.recv(4096)
            if eki is not None and eki in readable:
                self._poll_eki(0.0)
            with self._lock:
                if self._pending:  # arrived while waiting: applied first
                    return False
        self._follow_clock()
        self._answer_syncs(ran_cycle=False)
        with self._lock:
            wanted = any(cycles > 0 for cycles, _, _ in self._syncs)
        return wanted or not self._standing_still()

    def _follow_clock(self) -> None:
        """The cycles the clock passed while the robot stood: each exchanged, or with skip_idle only the last."""
        due = math.floor((self.clock.now() - self._t0) / self.cycle_s + 1e-9) + 1 - self._tick
        if due <= 0:
            return
        if self.skip_idle:
            self.idle_skipped += due - 1
            self._tick += due - 1
            due = 1
        for _ in range(due):
            if self._rsi.connected:
                self._rsi_exchange()
            self._tick += 1
            self.cycles += 1

    def _answer_syncs(self, ran_cycle: bool) -> None:
        if not self._syncs:  # read without the lock, as _apply_injections: one added now is answered next time
            return
        with self._lock:
            for request in self._syncs:
                if ran_cycle and request[0] > 0:
                    request[0] -= 1
            done = [r for r in self._syncs if r[0] <= 0]
            self._syncs = [r for r in self._syncs if r[0] > 0]
        if done and self._ipoc_sent is not None:
            self._await_delivery(self._ipoc_sent)
        for _, event, answer in done:
            answer.append(self._ipoc0 + self._ipoc_step * (self._tick - 1))  # the last cycle's, sent or not
            event.set()

    def _await_delivery(self, ipoc: int) -> None:
        """Until the client received the frame with this IPOC (a frame not received in time is lost)."""
        assert self._delivered is not None
        if self._ipoc_received is None or self._ipoc_received < ipoc:
            self._delivered(ipoc, LOCKSTEP_TIMEOUT_S)
            self._ipoc_received = ipoc

    def _apply_injections(self) -> None:
        if not self._pending:  # read without the lock (issue 41: once a cycle); one appended now is seen next cycle
            return
        with self._lock:
            pending, self._pending = self._pending, []
        for what, arg in pending:
            if what == "fault":
                self._fault = int(arg)  # type: ignore[arg-type]
            elif what == "drop":
                for channel in ("eki", "rsi") if arg == "both" else (str(arg),):
                    self._close(channel, f"{channel.upper()} connection dropped (injected)")
            elif what == "lose_rsi":
                self._wire_loses_rsi = bool(arg)
            elif what == "misreport":
                channel, axis, offset = arg  # type: ignore[misc]
                self._misreport.pop(channel, None)
                if offset:
                    self._misreport[channel] = (axis, offset)
            elif what == "garbage":
                channel, data = arg  # type: ignore[misc]
                if channel == "eki":
                    self._eki.send(data)
                else:
                    self._rsi.send(data)

    # --- EKI ------------------------------------------------------------------------------------------------

    def _poll_eki(self, timeout: float) -> None:
        if not self._eki.connected:
            if timeout:
                self.wall.sleep(timeout)
            return
        for doc in self._eki.receive(timeout):
            try:
                cmd = parse_command(doc)
            except ProtocolError as exc:
                self.errors.append(f"EKI: bad command: {exc}")
                self._report(command_id_of(doc) or 0, done=False, error=ERR_BAD_COMMAND)
                continue
            self.commands.append(cmd)
            if cmd.kind == KIND_STOP:  # StopPoll: only the running move can be stopped
                running = self.motion.command
                if running is not None and self.motion.mode == "moving" and cmd.command_id == running.command_id:
                    self.motion.brake()
            elif len(self._queue) >= _QUEUE_LIMIT:
                self.errors.append(f"EKI: buffer full, command {cmd.command_id} rejected")
                self._report(cmd.command_id, done=False, error=ERR_BAD_COMMAND)
            else:
                self._queue.append(cmd)

    def _report(self, command_id: int, done: bool, error: int) -> None:
        data = encode_state(RobotState(self._reported("eki"), command_id, done, error))
        self.eki_sent.append(data)
        self._eki.send(data)

    # --- the program: requests served, motion stepped -------------------------------------------------------

    def _halt(self, error: int) -> None:
        cmd = self.motion.halt()
        if cmd is not None:
            self._report(cmd.command_id, done=False, error=error)

    def _step(self) -> None:
        if self.motion.mode != "idle" and self._fault:
            self._halt(self._fault)
        if self.motion.mode == "idle" and self._queue:
            cmd = self._queue.popleft()
            if cmd.kind == KIND_RESET:
                if self._fault != ERR_RSI_STOPPED:  # E-stop released, drives on: only an RSI stop stays
                    self._fault = 0
                self._report(cmd.command_id, done=not self._fault, error=self._fault)
            elif cmd.kind != KIND_MOVE:
                self._report(cmd.command_id, done=False, error=ERR_BAD_COMMAND)
            elif self._fault:
                self._report(cmd.command_id, done=False, error=self._fault)
            elif any(not lo <= v <= hi for v, (lo, hi) in zip(cmd.target_deg, self.soft_limits_deg, strict=True)):
                self._report(cmd.command_id, done=False, error=ERR_SOFT_LIMIT)
            else:
                self.motion.begin(cmd)
        ended = self.motion.step()
        if ended is not None:
            cmd, done, error = ended
            self._report(cmd.command_id, done=done, error=error)

    # --- RSI ------------------------------------------------------------------------------------------------

    def _rsi_exchange(self) -> None:
        ipoc = self._ipoc0 + self._ipoc_step * self._tick
        frame = RobFrame(
            ipoc=ipoc,
            aipos=self._reported("rsi"),
            aspos=self.motion.set_deg,
            rist=_NO_POSE,
            rsol=_NO_POSE,
            delay=self.late_packets,
        )
        if self._wire_loses_rsi or not self._rsi.send(encode_rob(frame, tcp=self.rsi_protocol == "tcp")):
            return
        self.frames_sent += 1
        self._ipoc_sent = ipoc
        if self._delivered is not None and ipoc - (self._ipoc_received or 0) > LOCKSTEP_AHEAD * self._ipoc_step:
            # the frame just sent: the next LOCKSTEP_AHEAD go without waiting (issue 41: waiting for the one
            # LOCKSTEP_AHEAD back made every frame after the 64th wait, a delivery check per frame)
            self._await_delivery(ipoc)
        if self.rsi_passive:
            return
        if self._rsi.await_answer(ipoc, self.wall.now() + self.answer_budget_s, self.wall.now):
            self.consecutive_late = 0
            return
        if not self._rsi.connected:
            return
        self.late_packets += 1
        self.consecutive_late += 1
        if self.consecutive_late > self.max_late_packages:
            self._close(
                "rsi",
                f"RSI stopped: {self.consecutive_late} late answers in a row > "
                f"eERXmaxLatePackages={self.max_late_packages}",
            )

    def _rsi_lost(self) -> None:
        """Without its RSI partner the controller stops the robot (ST_ETHERNET error): sticky until restart."""
        self.rsi_stopped = True
        self._fault = ERR_RSI_STOPPED
        if self.motion.mode != "idle":
            self._halt(ERR_RSI_STOPPED)

    def _close(self, channel: str, why: str | None) -> None:
        (self._eki if channel == "eki" else self._rsi).close(why)
