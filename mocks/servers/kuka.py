"""Deterministic mock of a KUKA KR C2 running configs/krc2 (trackcal_eki.src + the RSI passive monitor).

Like the real controller it is the network *client*: it connects to the EKI and RSI ports where trackcal
listens, retrying (bounded by connect_timeout_s of wall time) until they are up. Then one thread runs the
controller:

    every 12 ms interpolation cycle (on the injected clock; the mock advances it with clock.sleep):
      read the EKI commands that arrived (FIFO, like the EKX buffer), step the motion, send one RSI <Rob>, and
      wait for the <Sen> answer with the same IPOC; an answer that misses the budget is late, and more than
      max_late_packages late answers in a row stop the robot (RSI error) as eERXmaxLatePackages does.

Motion is a synchronous PTP (all axes start and stop together) with a quintic profile
s(u) = 10u^3 - 15u^4 + 6u^5, whose peak speed is 1.875x the mean, so the duration is
T = 1.875 * max|dq| / (joint_speed_deg_s * speed% / 100). After arrival a damped residual oscillation
overshoot * exp(-t / (settle_s / 5)) * cos(2 pi 1.5 Hz t) decays (e^-5 < 1 % of it is left after settle_s):
this is what trackcal's wait_settled must see through. The program's dwell is settle_s; then the mock reports
$AXIS_ACT (4 decimals) in <RobotState>. Everything is computed from integer cycle counts (not accumulated
float time) and a random.Random(seed), so the same seed and the same commands give the same bytes; only how
many idle cycles run between commands depends on the wall-clock pace of the peer.

The answer budget is wall time (answer_budget_s, default 0.25 s): the real controller allows ~10 ms, which a
loaded CI machine running Python cannot promise; tests that need lateness set a small budget and a slow
client.

Fault injection: estop(), drives_off() (reported as RobotState Error 1/2, see drivers.kuka.eki_codec), a
target outside soft_limits_deg (Error 3), RSI stop after late answers (Error 4), drop_connection("eki"|"rsi"),
send_garbage("eki"|"rsi"). Garbage from the peer never raises out of the thread: it is recorded in `errors`
and the connection it came on is dropped (a stream cannot be resynchronised).

The element and attribute names come from the codecs; at construction the mock checks that the shipped EKX
config (configs/krc2/TrackcalEki+.xml) and RSI config (configs/krc2/trackcal_rsi.xml) declare exactly those.
"""

from __future__ import annotations

import contextlib
import math
import random
import select
import socket
import threading
import xml.etree.ElementTree as ET
from collections import deque
from collections.abc import Callable, Sequence
from importlib import resources
from pathlib import Path

from drivers.errors import ProtocolError
from drivers.interfaces import RealClock
from drivers.kuka.eki_codec import (
    AXES,
    COMMAND_ROOT,
    COMMAND_TAGS,
    ERR_BAD_COMMAND,
    ERR_DRIVES_OFF,
    ERR_ESTOP,
    ERR_RSI_STOPPED,
    ERR_SOFT_LIMIT,
    STATE_TAGS,
    MoveCommand,
    RobotState,
    XmlStreamFramer,
    command_id_of,
    encode_state,
    parse_command,
)
from drivers.kuka.rsi_codec import (
    CART,
    CORRECTION_ELEMENT,
    CYCLE_S,
    MAX_FRAME_BYTES,
    RobFrame,
    encode_rob,
    parse_sen,
    sen_framer,
)

CONFIG_DIR = Path(str(resources.files("configs") / "krc2"))  # shipped as package data
EKX_STRUCTURE_FILE = "TrackcalEki+.xml"
RSI_CONFIG_FILE = "trackcal_rsi.xml"
DEFAULT_SOFT_LIMITS_DEG = (
    (-185.0, 185.0),
    (-146.0, 0.0),
    (-119.0, 155.0),
    (-350.0, 350.0),
    (-125.0, 125.0),
    (-350.0, 350.0),
)
IPOC_STEP_MS = 12
_QUEUE_LIMIT = 16
_RESIDUAL_HZ = 1.5


def eki_config_tags(config_dir: Path = CONFIG_DIR) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(RECEIVE tags, SEND tags) declared by the shipped EKX structure file, in file order."""
    root = ET.parse(config_dir / EKX_STRUCTURE_FILE).getroot()
    receive = tuple(e.get("Tag", "") for e in root.iterfind("RECEIVE/XML/ELEMENT"))
    send = tuple(e.get("Tag", "") for e in root.iterfind("SEND/XML/ELEMENT"))
    return receive, send


def rsi_config(config_dir: Path = CONFIG_DIR) -> dict:
    """The shipped RSI XML config: protocol, Sen type, SEND and RECEIVE element tags."""
    root = ET.parse(config_dir / RSI_CONFIG_FILE).getroot()
    return {
        "protocol": (root.findtext("CONFIG/PROTOCOL") or "").strip().upper(),
        "sentype": (root.findtext("CONFIG/SENTYPE") or "").strip(),
        "onlysend": (root.findtext("CONFIG/ONLYSEND") or "").strip().upper(),
        "port": int((root.findtext("CONFIG/PORT") or "0").strip()),
        "send": tuple(e.get("TAG", "") for e in root.iterfind("SEND/ELEMENTS/ELEMENT")),
        "receive": tuple(e.get("TAG", "") for e in root.iterfind("RECEIVE/ELEMENTS/ELEMENT")),
    }


def check_configs(config_dir: Path = CONFIG_DIR) -> str:
    """Raise ValueError if the shipped configs and the codecs disagree; returns the configured Sen type."""
    receive, send = eki_config_tags(config_dir)
    if set(receive) != set(COMMAND_TAGS) or len(receive) != len(COMMAND_TAGS):
        raise ValueError(f"{EKX_STRUCTURE_FILE} RECEIVE {receive} != codec {COMMAND_TAGS}")
    if set(send) != set(STATE_TAGS) or len(send) != len(STATE_TAGS):
        raise ValueError(f"{EKX_STRUCTURE_FILE} SEND {send} != codec {STATE_TAGS}")
    rsi = rsi_config(config_dir)
    expected_send = ("DEF_RIst", "DEF_RSol", "DEF_AIPos", "DEF_ASPos", "DEF_Delay")
    if rsi["send"] != expected_send:
        raise ValueError(f"{RSI_CONFIG_FILE} SEND {rsi['send']} != {expected_send}")
    expected_receive = tuple(f"{CORRECTION_ELEMENT}.{a}" for a in AXES)
    if rsi["receive"] != expected_receive:
        raise ValueError(f"{RSI_CONFIG_FILE} RECEIVE {rsi['receive']} != {expected_receive}")
    if not rsi["sentype"]:
        raise ValueError(f"{RSI_CONFIG_FILE} has no SENTYPE")
    return rsi["sentype"]


def _quintic(u: float) -> float:
    return u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)


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
        rsi_protocol: str = "tcp",
        soft_limits_deg: Sequence[tuple[float, float]] = DEFAULT_SOFT_LIMITS_DEG,
        max_late_packages: int = 10,
        answer_budget_s: float = 0.25,
        connect_timeout_s: float = 10.0,
        overshoot_deg: float = 0.02,
        wall_clock=None,
        config_dir: Path = CONFIG_DIR,
    ) -> None:
        if rsi_protocol not in ("tcp", "udp"):
            raise ValueError("rsi_protocol must be 'tcp' or 'udp'")
        q0 = tuple(float(v) for v in initial_joints_deg)
        if len(q0) != len(AXES):
            raise ValueError(f"initial_joints_deg needs {len(AXES)} values")
        self.sen_type = check_configs(config_dir)
        self.eki_addr, self.rsi_addr = eki_addr, rsi_addr
        self.clock = clock
        self.wall = wall_clock or RealClock()  # network waits are real; the controller's own time is `clock`
        self.joint_speed_deg_s = float(joint_speed_deg_s)
        self.settle_s = float(settle_s)
        self.on_joints = on_joints
        self.rsi_protocol = rsi_protocol
        self.soft_limits_deg = tuple((float(lo), float(hi)) for lo, hi in soft_limits_deg)
        self.max_late_packages = int(max_late_packages)
        self.answer_budget_s = float(answer_budget_s)
        self.connect_timeout_s = float(connect_timeout_s)
        self.overshoot_deg = float(overshoot_deg)
        self._rng = random.Random(seed)
        self._ipoc = IPOC_STEP_MS * self._rng.randrange(10**6, 10**7)

        self._q = list(q0)  # actual joints
        self._q_set = list(q0)  # set point
        self._mode = "idle"
        self._cmd: MoveCommand | None = None
        self._start: tuple[float, ...] = q0
        self._target: tuple[float, ...] = q0
        self._dirs = (0.0,) * 6
        self._amp = 0.0
        self._k = 0  # cycles into the current motion phase
        self._n_move = 0
        self._n_dwell = max(1, math.ceil(self.settle_s / CYCLE_S - 1e-9))
        self._since_arrival: int | None = None
        self._queue: deque[MoveCommand] = deque()
        self._fault = 0
        self._last_reported: tuple[float, ...] | None = None

        self._lock = threading.Lock()
        self._pending: list[tuple[str, object]] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._eki: socket.socket | None = None
        self._rsi: socket.socket | None = None
        self._eki_framer = XmlStreamFramer(COMMAND_ROOT)
        self._sen_framer = sen_framer()

        # observable state for tests
        self.cycles = 0
        self.late_packets = 0
        self.consecutive_late = 0
        self.rsi_stopped = False
        self.errors: list[str] = []
        self.commands: list[MoveCommand] = []
        self.eki_sent: list[bytes] = []
        self.crashed: BaseException | None = None
        self.connected = threading.Event()

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

    def join(self, timeout: float) -> bool:
        """Wait (wall time) for the controller thread to end; True if it did."""
        if self._thread is not None:
            self._thread.join(timeout)
            return not self._thread.is_alive()
        return True

    @property
    def joints_deg(self) -> tuple[float, ...]:
        return tuple(round(v, 4) for v in self._q)

    # --- fault injection (any thread) -----------------------------------------------------------------------

    def estop(self) -> None:
        self._inject("fault", ERR_ESTOP)

    def drives_off(self) -> None:
        self._inject("fault", ERR_DRIVES_OFF)

    def reset_faults(self) -> None:
        self._inject("fault", 0)

    def drop_connection(self, channel: str = "eki") -> None:
        self._inject("drop", channel)

    def send_garbage(
        self, channel: str = "rsi", data: bytes = b'<Rob TYPE="KUKA"><AIPos A1=\x00\xff garbage'
    ) -> None:
        self._inject("garbage", (channel, data))

    def _inject(self, what: str, arg: object) -> None:
        with self._lock:
            self._pending.append((what, arg))

    # --- thread ---------------------------------------------------------------------------------------------

    def _run(self) -> None:
        try:
            if not self._connect():
                return
            self.connected.set()
            while not self._stop.is_set() and (self._eki is not None or self._rsi is not None):
                self._cycle()
        except BaseException as exc:  # a mock must never die silently: tests assert crashed is None
            self.crashed = exc
            self.errors.append(f"mock crashed: {exc!r}")
        finally:
            self._close("eki", None)
            self._close("rsi", None)

    def _connect(self) -> bool:
        deadline = self.wall.now() + self.connect_timeout_s
        self._eki = self._connect_tcp(self.eki_addr, deadline, "EKI")
        if self._eki is None:
            return False
        if self.rsi_protocol == "tcp":
            self._rsi = self._connect_tcp(self.rsi_addr, deadline, "RSI")
            if self._rsi is None:
                return False
        else:
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.connect(self.rsi_addr)
            self._rsi = sock
        self._send_rsi(
            encode_rob(RobFrame(ipoc=None), tcp=self.rsi_protocol == "tcp")
        )  # KR C2: empty IPOC first
        return True

    def _connect_tcp(self, addr: tuple[str, int], deadline: float, what: str) -> socket.socket | None:
        last: OSError | None = None
        while not self._stop.is_set() and self.wall.now() < deadline:
            try:
                sock = socket.create_connection(addr, timeout=max(0.05, min(1.0, deadline - self.wall.now())))
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                sock.settimeout(None)
                return sock
            except OSError as exc:
                last = exc
                self.wall.sleep(0.02)
        self.errors.append(
            f"{what}: could not connect to {addr[0]}:{addr[1]} within {self.connect_timeout_s} s ({last})"
        )
        return None

    def _cycle(self) -> None:
        self._apply_injections()
        self._poll_eki(0.0 if self._rsi is not None else CYCLE_S)
        self._step()
        q = self.joints_deg
        if self.on_joints is not None and q != self._last_reported:
            self._last_reported = q
            self.on_joints(q)
        if self._rsi is not None:
            self._rsi_exchange()
        self.clock.sleep(CYCLE_S)
        self.cycles += 1

    def _apply_injections(self) -> None:
        with self._lock:
            pending, self._pending = self._pending, []
        for what, arg in pending:
            if what == "fault":
                if arg == 0:
                    if not self.rsi_stopped:
                        self._fault = 0
                else:
                    self._fault = int(arg)  # type: ignore[arg-type]
            elif what == "drop":
                for channel in ("eki", "rsi") if arg == "both" else (str(arg),):
                    self._close(channel, f"{channel.upper()} connection dropped (injected)")
            elif what == "garbage":
                channel, data = arg  # type: ignore[misc]
                if channel == "eki":
                    self._send_eki(data)
                else:
                    self._send_rsi(data)

    # --- EKI ------------------------------------------------------------------------------------------------

    def _poll_eki(self, timeout: float) -> None:
        sock = self._eki
        if sock is None:
            if timeout:
                self.wall.sleep(timeout)
            return
        try:
            readable, _, _ = select.select([sock], [], [], timeout)
            if not readable:
                return
            data = sock.recv(4096)
        except OSError as exc:
            self._close("eki", f"EKI receive failed: {exc}")
            return
        if not data:
            self._close("eki", "trackcal closed the EKI connection")
            return
        try:
            docs = self._eki_framer.feed(data)
        except ProtocolError as exc:
            self._close("eki", f"EKI: unreadable stream, connection dropped: {exc}")
            return
        for doc in docs:
            try:
                cmd = parse_command(doc)
            except ProtocolError as exc:
                self.errors.append(f"EKI: bad command: {exc}")
                self._report(command_id_of(doc) or 0, done=False, error=ERR_BAD_COMMAND)
                continue
            self.commands.append(cmd)
            if len(self._queue) >= _QUEUE_LIMIT:
                self.errors.append(f"EKI: buffer full, command {cmd.command_id} rejected")
                self._report(cmd.command_id, done=False, error=ERR_BAD_COMMAND)
            else:
                self._queue.append(cmd)

    def _report(self, command_id: int, done: bool, error: int) -> None:
        data = encode_state(RobotState(self.joints_deg, command_id, done, error))
        self.eki_sent.append(data)
        self._send_eki(data)

    def _send_eki(self, data: bytes) -> None:
        if self._eki is None:
            return
        try:
            self._eki.sendall(data)
        except OSError as exc:
            self._close("eki", f"EKI send failed: {exc}")

    # --- motion ---------------------------------------------------------------------------------------------

    def _residual(self, k: int) -> float:
        t = k * CYCLE_S
        tau = max(self.settle_s / 5.0, CYCLE_S)
        if t / tau > 40.0:
            return 0.0
        return self._amp * math.exp(-t / tau) * math.cos(2.0 * math.pi * _RESIDUAL_HZ * t)

    def _halt(self, error: int) -> None:
        cmd = self._cmd
        self._target = self._start = tuple(self._q)
        self._q_set = list(self._q)
        self._amp, self._since_arrival, self._mode, self._cmd = 0.0, None, "idle", None
        if cmd is not None:
            self._report(cmd.command_id, done=False, error=error)

    def _step(self) -> None:
        if self._mode != "idle" and self._fault:
            self._halt(self._fault)
        if self._mode == "idle" and self._queue:
            cmd = self._queue.popleft()
            if self._fault:
                self._report(cmd.command_id, done=False, error=self._fault)
            elif any(
                not lo <= v <= hi for v, (lo, hi) in zip(cmd.target_deg, self.soft_limits_deg, strict=True)
            ):
                self._report(cmd.command_id, done=False, error=ERR_SOFT_LIMIT)
            else:
                self._begin(cmd)
        if self._mode == "moving":
            self._k += 1
            u = min(1.0, self._k / self._n_move)
            p = _quintic(u)
            self._q = [a + (b - a) * p for a, b in zip(self._start, self._target, strict=True)]
            self._q_set = list(self._q)
            if self._k >= self._n_move:
                self._mode, self._k, self._since_arrival = "dwell", 0, 0
            return
        if self._since_arrival is not None:  # the residual oscillation decays, dwelling or not
            self._since_arrival += 1
            r = self._residual(self._since_arrival)
            self._q = [t + d * r for t, d in zip(self._target, self._dirs, strict=True)]
            self._q_set = list(self._target)
            if r == 0.0:
                self._since_arrival = None
        if self._mode == "dwell":  # counted apart from the oscillation: without overshoot it still ends
            self._k += 1
            if self._k >= self._n_dwell:  # WAIT SEC 0 + dwell done: report $AXIS_ACT
                assert self._cmd is not None
                self._report(self._cmd.command_id, done=True, error=0)
                self._mode, self._cmd = "idle", None

    def _begin(self, cmd: MoveCommand) -> None:
        start = tuple(self._q)
        deltas = [b - a for a, b in zip(start, cmd.target_deg, strict=True)]
        span = max(abs(d) for d in deltas)
        speed = self.joint_speed_deg_s * cmd.speed_pct / 100.0
        self._cmd, self._start, self._target = cmd, start, tuple(cmd.target_deg)
        self._dirs = tuple(d / span for d in deltas) if span > 0 else (0.0,) * 6
        self._amp = self.overshoot_deg * (0.5 + 0.5 * self._rng.random()) if span > 0 else 0.0
        self._n_move = math.ceil(1.875 * span / speed / CYCLE_S - 1e-9) if span > 0 else 0
        self._k = 0
        if self._n_move == 0:
            self._mode, self._since_arrival = "dwell", 0
        else:
            self._mode, self._since_arrival = "moving", None

    # --- RSI ------------------------------------------------------------------------------------------------

    def _send_rsi(self, data: bytes) -> bool:
        if self._rsi is None:
            return False
        try:
            self._rsi.sendall(data) if self.rsi_protocol == "tcp" else self._rsi.send(data)
            return True
        except OSError as exc:
            self._close("rsi", f"RSI send failed: {exc}")
            return False

    def _rsi_exchange(self) -> None:
        ipoc = self._ipoc
        self._ipoc += IPOC_STEP_MS
        frame = RobFrame(
            ipoc=ipoc,
            aipos=self.joints_deg,
            aspos=tuple(round(v, 4) for v in self._q_set),
            rist=(0.0,) * len(CART),
            rsol=(0.0,) * len(CART),
            delay=self.late_packets,
        )
        if not self._send_rsi(encode_rob(frame, tcp=self.rsi_protocol == "tcp")):
            return
        if self._await_answer(ipoc):
            self.consecutive_late = 0
            return
        if self._rsi is None:
            return
        self.late_packets += 1
        self.consecutive_late += 1
        if self.consecutive_late > self.max_late_packages:
            self._close(
                "rsi",
                f"RSI stopped: {self.consecutive_late} late answers in a row > "
                f"eERXmaxLatePackages={self.max_late_packages}",
            )

    def _await_answer(self, ipoc: int) -> bool:
        deadline = self.wall.now() + self.answer_budget_s
        while True:
            sock = self._rsi
            if sock is None:
                return False
            remaining = deadline - self.wall.now()
            if remaining <= 0:
                return False
            try:
                readable, _, _ = select.select([sock], [], [], remaining)
                if not readable:
                    continue
                data = sock.recv(4096 if self.rsi_protocol == "tcp" else MAX_FRAME_BYTES + 1)
            except OSError as exc:
                self._close("rsi", f"RSI receive failed: {exc}")
                return False
            if self.rsi_protocol == "tcp":
                if not data:
                    self._close("rsi", "trackcal closed the RSI connection")
                    return False
                try:
                    docs = self._sen_framer.feed(data)
                except ProtocolError as exc:
                    self._close("rsi", f"RSI: unreadable answer stream, connection dropped: {exc}")
                    return False
            else:
                docs = [data]
            ok = False
            for doc in docs:
                try:
                    sen = parse_sen(doc)
                except ProtocolError as exc:
                    self.errors.append(f"RSI: bad answer: {exc}")
                    continue
                if sen.sen_type != self.sen_type:
                    self.errors.append(f"RSI: answer of Type {sen.sen_type!r}, configured {self.sen_type!r}")
                elif sen.ipoc == ipoc:
                    ok = True  # answers with another IPOC are stale answers to late packets: ignored
            if ok:
                return True

    def _close(self, channel: str, why: str | None) -> None:
        attr = "_eki" if channel == "eki" else "_rsi"
        sock = getattr(self, attr)
        setattr(self, attr, None)
        if sock is None:
            return
        if why:
            self.errors.append(why)
        with contextlib.suppress(OSError):
            sock.shutdown(socket.SHUT_RDWR)
        with contextlib.suppress(OSError):
            sock.close()
        if channel == "rsi" and why is not None:
            # without its RSI partner the controller stops the robot (ST_ETHERNET error): sticky until restart
            self.rsi_stopped = True
            self._fault = ERR_RSI_STOPPED
            if self._mode != "idle":
                self._halt(ERR_RSI_STOPPED)
