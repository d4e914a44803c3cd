"""KUKA KR C2 client (drivers.interfaces.Robot): EKI for motion, RSI 2.x as a joint monitor.

On the KR C2 both interfaces have the controller as the network *client*: trackcal listens on two ports and
the robot connects (Ethernet KRL XML 1.2: external system = server, ros-industrial/kuka_experimental pull request
#205's PC side accepts the controller's connection; RSI: ST_ETHERNET connects to IP_NUMBER/PORT of its XML config,
kuka_experimental kuka_rsi_hw_interface/krl/KR_C2/ros_rsi_ethernet.xml). The programs and configs the controller
needs are in configs/krc2/ (see configs/krc2/README.md); the RSI defaults (protocol, passive) are the shipped
configs/krc2/trackcal_rsi.xml's.

- EKI (TCP): one <RobotCommand> per request (drivers.kuka.eki_codec): a move, a stop of the running move, a
  reset of the fault flags; the KRL program answers moves and resets with one <RobotState>. The echoed ID is the
  acknowledgement; Error != 0 -> DeviceFault (its code).
- RSI (UDP by default, as on a KR C2; TCP available): one thread receives the <Rob> frames and, unless passive
  (ONLYSEND TRUE: the controller expects no answer), answers each at once with <Sen>, zero corrections and the same
  IPOC, found without parsing the frame (drivers.kuka.rsi_codec.ipoc_of). That thread does nothing else: a second
  one parses the frames and keeps the latest AIPos (0.0001 deg), because a controller in answered mode stops the
  robot after more than eERXmaxLatePackages late answers.
- A move is refused when the RSI stream is stale: no complete frame for more than STALE_CYCLES cycles; the
  client waits at most rsi_stale_s for a fresh one before it refuses, and never sends the move.
- `motion_guard` (a callable returning None, or why the robot must stop) is polled at least every GUARD_S
  (25 Hz) during every move and settle: during a move it makes the client send the stop request (the KRL
  brakes) and the move end in DeviceFault code ERR_STOPPED; during settling it ends the wait the same way.
- Settling (`wait_settled`) is judged on RSI frames in controller time: one frame = one interpolation cycle of
  rsi_cycle_s (12 ms on a KR C2, 4 ms on a KR C4: the hardware file says which). The same code is then right for
  the real robot and for the mock controller on a virtual clock. A real-time guard (timeout_s + rsi_stale_s)
  still bounds the wait if frames stop coming.
- Simulation only (`rsi_sync` given: `run --sim`, the mock controller in the same process on a virtual clock,
  where a standing robot's controller time passes only when somebody waits for it): before reading what the
  stream says while the robot stands (joints, the freshness check before a move, the settling window) the
  client asks the controller for its frame of now, or for the cycles its window still needs, and judges
  freshness in controller time: the latest frame's IPOC at most STALE_CYCLES cycles behind the controller's (the
  IPOC counts milliseconds of controller time, kuka_rsi_simulator in ros-industrial/kuka_experimental).
  Without `rsi_sync` (a real controller, `trackcal mock`) nothing of this runs: every cycle's frame is received
  as it comes and freshness is wall time.

Trust: only the controller is served. Both listeners bind to the configured local address (the hardware
config names it: there is no 0.0.0.0 default), a TCP connection from any other address than
`controller_host`'s is closed at once (counted in `refused_peers`) and the accept goes on until the controller
comes, a UDP datagram from elsewhere is ignored; each channel serves one connection, the first from the
controller, and accepts no other while it lasts.

Targets are checked before anything is sent (joint limits, then the optional cell-box callable):
MotionRefused.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import queue
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence

from trackcal.drivers.errors import (
    ConnectionLost,
    DeviceError,
    DeviceFault,
    DeviceTimeout,
    MotionRefused,
    ProtocolError,
)
from trackcal.drivers.kuka.eki_codec import (
    AXES,
    ERR_STOPPED,
    ERROR_TEXT,
    KIND_MOVE,
    KIND_RESET,
    KIND_STOP,
    MAX_ID,
    STATE_ROOT,
    Command,
    RobotState,
    XmlStreamFramer,
    encode_command,
    parse_state,
)
from trackcal.drivers.kuka.rsi_codec import (
    KRC2_CYCLE_S,
    MAX_FRAME_BYTES,
    SHIPPED,
    SenFrame,
    encode_sen,
    ipoc_of,
    parse_rob,
    rob_framer,
)

_POLL_S = 0.05  # socket timeout slice of the background threads and of blocking reads
GUARD_S = 0.04  # the motion guard is polled at least this often during moves and settling (25 Hz >= 20 Hz)
STALE_CYCLES = 5  # a move is refused when no complete RSI frame came for more than this many cycles
_RECV_BYTES = 4096
_FRAME_HISTORY = 8192  # RSI frames kept for wait_settled (~98 s of 12 ms cycles)

CellBoxCheck = Callable[[tuple[float, ...]], "str | None"]
MotionGuard = Callable[[], "str | None"]
RsiSync = Callable[[int], "int | None"]  # run n more cycles (0: none), the IPOC of the controller's last frame


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
    ) -> None:
        if rsi_protocol not in ("tcp", "udp"):
            raise ValueError(f"rsi_protocol must be 'tcp' or 'udp', got {rsi_protocol!r}")
        for name, v in (
            ("connect_timeout_s", connect_timeout_s),
            ("move_timeout_s", move_timeout_s),
            ("io_timeout_s", io_timeout_s),
            ("rsi_stale_s", rsi_stale_s),
            ("rsi_cycle_s", rsi_cycle_s),
        ):
            if not v > 0:
                raise ValueError(f"{name} must be positive: nothing waits forever")
        limits = tuple((float(lo), float(hi)) for lo, hi in joint_limits_deg)
        if len(limits) != len(AXES) or any(not lo < hi for lo, hi in limits):
            raise ValueError(f"joint_limits_deg needs {len(AXES)} (low, high) pairs with low < high")
        self.eki_host, self.eki_port = eki_host, int(eki_port)
        self.rsi_host, self.rsi_port = rsi_host, int(rsi_port)
        self.rsi_protocol = rsi_protocol
        self.controller_host = controller_host
        self.refused_peers: list[tuple[str, int]] = []  # (address, port) of connections and datagrams refused
        self._controller_ips: frozenset[str] | None = None
        self.rsi_passive = bool(rsi_passive)
        self.rsi_cycle_s = float(rsi_cycle_s)
        self.joint_limits_deg = limits
        self.cell_box_check = cell_box_check
        self.motion_guard = motion_guard
        self.connect_timeout_s = connect_timeout_s
        self.move_timeout_s = move_timeout_s
        self.io_timeout_s = io_timeout_s
        self.rsi_stale_s = rsi_stale_s
        self.rsi_sync = rsi_sync
        self._ipoc_step = max(1, round(self.rsi_cycle_s * 1000))  # IPOC: milliseconds of controller time
        mode = "passive" if self.rsi_passive else "answered"
        self.device = f"KR C2 eki {eki_host}:{eki_port} rsi {rsi_protocol} {mode} {rsi_host}:{rsi_port}"

        self._eki_listener: socket.socket | None = None
        self._rsi_listener: socket.socket | None = None  # TCP listener, or the bound UDP socket
        self._eki: socket.socket | None = None
        self._rsi: socket.socket | None = None
        self._rsi_peer: tuple | None = None  # UDP: where the controller sends from
        self._eki_framer = XmlStreamFramer(STATE_ROOT)
        self._ids = itertools.count(1)

        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._inbox: queue.SimpleQueue = queue.SimpleQueue()  # (arrival time, frame) from answer to monitor
        self._rsi_error: DeviceError | None = None
        self._frames: deque[tuple[int, tuple[float, ...]]] = deque(maxlen=_FRAME_HISTORY)
        self._seq = 0
        self._latest: tuple[float, ...] | None = None
        self._latest_at: float | None = None
        self._latest_ipoc: int | None = None
        self._last_bad = ""
        self._framer_pending = 0
        self.rsi_frames_answered = 0
        self.rsi_frames_unreadable = 0

    # --- addresses and connection ---------------------------------------------------------------------------

    @property
    def eki_address(self) -> tuple[str, int]:
        self.listen()
        assert self._eki_listener is not None
        return self._eki_listener.getsockname()[:2]

    @property
    def rsi_address(self) -> tuple[str, int]:
        self.listen()
        assert self._rsi_listener is not None
        return self._rsi_listener.getsockname()[:2]

    def listen(self) -> None:
        """Open both listening ports (port 0 picks a free one; see eki_address / rsi_address). Idempotent."""
        if self._controller_ips is None:
            self._controller_ips = self._resolve_controller()
        if self._eki_listener is None:
            self._eki_listener = self._bind(socket.SOCK_STREAM, self.eki_host, self.eki_port, "EKI")
        if self._rsi_listener is None:
            kind = socket.SOCK_STREAM if self.rsi_protocol == "tcp" else socket.SOCK_DGRAM
            self._rsi_listener = self._bind(kind, self.rsi_host, self.rsi_port, "RSI")

    def _resolve_controller(self) -> frozenset[str]:
        try:
            infos = socket.getaddrinfo(self.controller_host, None)
        except OSError as exc:
            raise ConnectionLost(
                f"cannot resolve the controller's address {self.controller_host}: {exc}", device=self.device
            ) from exc
        return frozenset(_plain_ip(info[4][0]) for info in infos)

    def _from_controller(self, peer: tuple) -> bool:
        assert self._controller_ips is not None
        if _plain_ip(peer[0]) in self._controller_ips:
            return True
        self.refused_peers.append((peer[0], peer[1]))
        return False

    def _refused(self) -> str:
        if not self.refused_peers:
            return ""
        who = ", ".join(sorted({a for a, _ in self.refused_peers}))
        return f" (refused {len(self.refused_peers)} from {who}: not the controller {self.controller_host})"

    def _bind(self, kind: int, host: str, port: int, what: str) -> socket.socket:
        try:
            infos = socket.getaddrinfo(host, port, type=kind)
            family, _, _, _, addr = infos[0]
            sock = socket.socket(family, kind)
        except OSError as exc:
            raise ConnectionLost(f"cannot resolve {what} address {host}:{port}: {exc}", device=self.device) from exc
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind(addr)
            if kind == socket.SOCK_STREAM:
                sock.listen(1)
        except OSError as exc:
            sock.close()
            raise ConnectionLost(f"cannot listen for {what} on {host}:{port}: {exc}", device=self.device) from exc
        return sock

    def connect(self) -> None:
        """Listen; accept the controller's EKI connection and first RSI frame within connect_timeout_s."""
        if self._eki is not None:
            return
        self.listen()
        deadline = time.monotonic() + self.connect_timeout_s
        try:
            eki_host, eki_port = self.eki_address
            self._eki = self._accept(
                self._eki_listener,
                deadline,
                f"the KR C2's EKI connection (EKX_Open of trackcal_eki) on {eki_host}:{eki_port}",
            )
            self._eki.settimeout(self.io_timeout_s)
            rsi_host, rsi_port = self.rsi_address
            what = f"the KR C2's RSI {self.rsi_protocol.upper()} stream (ST_ETHERNET of trackcal_rsi.xml) on "
            what += f"{rsi_host}:{rsi_port}"
            if self.rsi_protocol == "tcp":
                self._rsi = self._accept(self._rsi_listener, deadline, what)
            else:
                self._rsi = self._first_datagram(deadline, what)
        except BaseException:
            self.close()
            raise
        self._stop.clear()
        self._threads = [
            threading.Thread(target=self._rsi_answer_loop, name="krc2-rsi-answer", daemon=True),
            threading.Thread(target=self._rsi_monitor_loop, name="krc2-rsi-monitor", daemon=True),
        ]
        for thread in self._threads:
            thread.start()

    def _accept(self, listener: socket.socket | None, deadline: float, what: str) -> socket.socket:
        """The first connection from the controller; any other is closed at once."""
        assert listener is not None
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeout(
                    f"no connection within {self.connect_timeout_s} s: waited for {what}{self._refused()}",
                    device=self.device,
                )
            listener.settimeout(remaining)
            try:
                conn, peer = listener.accept()
            except TimeoutError:
                continue
            except OSError as exc:
                raise ConnectionLost(f"accept failed while waiting for {what}: {exc}", device=self.device) from exc
            if self._from_controller(peer):
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                return conn
            with contextlib.suppress(OSError):
                conn.close()

    def _first_datagram(self, deadline: float, what: str) -> socket.socket:
        sock = self._rsi_listener
        assert sock is not None
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeout(
                    f"no datagram within {self.connect_timeout_s} s: waited for {what}{self._refused()}",
                    device=self.device,
                )
            sock.settimeout(remaining)
            try:
                data, peer = sock.recvfrom(MAX_FRAME_BYTES + 1)
            except TimeoutError:
                continue
            except OSError as exc:
                raise ConnectionLost(f"UDP receive failed while waiting for {what}: {exc}", device=self.device) from exc
            if not self._from_controller(peer):
                continue
            self._rsi_peer, self._rsi = peer, sock
            self._take(sock, data)  # the KR C2's first frame (empty IPOC) normally
            return sock

    # --- RSI: the answering thread (nothing else) and the monitor thread ---------------------------------------

    def _rsi_answer_loop(self) -> None:
        sock = self._rsi
        assert sock is not None
        framer = rob_framer()
        sock.settimeout(_POLL_S)
        try:
            while not self._stop.is_set():
                try:
                    if self.rsi_protocol == "tcp":
                        data = sock.recv(_RECV_BYTES)
                        if not data:
                            raise ConnectionLost("the controller closed the RSI connection", device=self.device)
                        for doc in framer.feed(data):
                            self._take(sock, doc)
                        self._framer_pending = framer.pending
                    else:
                        data, peer = sock.recvfrom(MAX_FRAME_BYTES + 1)
                        if peer == self._rsi_peer:  # anything else is not our controller
                            self._take(sock, data)
                except TimeoutError:
                    continue
        except DeviceError as exc:
            if not exc.device:  # e.g. the framer's ProtocolError: name the device and the interface
                exc = type(exc)(f"RSI: {exc}", device=self.device)
            self._inbox.put((time.monotonic(), exc))
        except OSError as exc:
            if not self._stop.is_set():
                self._inbox.put((time.monotonic(), ConnectionLost(f"RSI connection failed: {exc}", device=self.device)))

    def _take(self, sock: socket.socket, doc: bytes) -> None:
        """Answer a frame at once (unless passive) and hand it to the monitor thread."""
        arrived = time.monotonic()
        if not self.rsi_passive:
            ipoc = ipoc_of(doc)
            if ipoc is not None:
                answer = encode_sen(SenFrame(ipoc=ipoc))
                if self.rsi_protocol == "tcp":
                    sock.sendall(answer)
                else:
                    sock.sendto(answer, self._rsi_peer)
                self.rsi_frames_answered += 1
        self._inbox.put((arrived, doc))

    def _rsi_monitor_loop(self) -> None:
        while not self._stop.is_set():
            try:
                arrived, item = self._inbox.get(timeout=_POLL_S)
            except queue.Empty:
                continue
            if isinstance(item, DeviceError):
                self._set_rsi_error(item)
                return
            try:
                frame = parse_rob(item)
            except ProtocolError as exc:
                if self.rsi_protocol == "tcp":  # a byte stream cannot be resynchronised
                    self._set_rsi_error(ProtocolError(f"RSI: {exc}", device=self.device))
                    return
                with self._cond:  # one bad datagram is not the end of the stream: the stale check decides
                    self.rsi_frames_unreadable += 1
                    self._last_bad = str(exc)
                continue
            if frame.ipoc is None:
                continue  # KR C2 first frame: nothing in it
            assert frame.aipos is not None
            joints = tuple(round(v, 4) for v in frame.aipos)
            with self._cond:
                self._seq += 1
                self._frames.append((self._seq, joints))
                self._latest, self._latest_at, self._latest_ipoc = joints, arrived, frame.ipoc
                self._cond.notify_all()

    def frame_received(self, ipoc: int, timeout_s: float) -> bool:
        """Simulation hook (the lockstep mock controller waits on it): True once a frame with this IPOC or a later
        one was received, False after timeout_s or an RSI error."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._latest_ipoc is None or self._latest_ipoc < ipoc:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or self._rsi_error is not None or self._stop.is_set():
                    return False
                self._cond.wait(remaining)
            return True

    def _synced_lag(self) -> int | None:
        """Simulation (rsi_sync): the controller's stream brought up to its clock, how many cycles the latest frame
        received is behind the controller's last one (None: no frame received, or no answer from it)."""
        assert self.rsi_sync is not None
        current = self.rsi_sync(0)
        with self._cond:
            if current is None or self._latest_ipoc is None:
                return None
            return max(0, current - self._latest_ipoc) // self._ipoc_step

    def _set_rsi_error(self, exc: DeviceError) -> None:
        with self._cond:
            if self._rsi_error is None:
                self._rsi_error = exc
            self._cond.notify_all()

    def _raise_rsi_error(self) -> None:
        if self._rsi_error is not None:
            raise self._rsi_error

    def _require_fresh_rsi(self) -> None:
        """Return once a complete RSI frame is at most STALE_CYCLES cycles old; waits for one at most rsi_stale_s,
        then refuses (MotionRefused, code rsi_stale): no move is sent without a live monitor."""
        limit = STALE_CYCLES * self.rsi_cycle_s
        deadline = time.monotonic() + self.rsi_stale_s
        lag = self._synced_lag() if self.rsi_sync is not None else None
        with self._cond:
            self._raise_rsi_error()
            if self.rsi_sync is not None:  # simulation: in controller time
                if lag is not None and lag <= STALE_CYCLES:
                    return
                age = "ever" if lag is None else f"{lag} cycles"
            else:
                while True:
                    self._raise_rsi_error()
                    now = time.monotonic()
                    if self._latest_at is not None and now - self._latest_at <= limit:
                        return
                    if now >= deadline:
                        break
                    self._cond.wait(min(deadline - now, limit))
                age = "ever" if self._latest_at is None else f"{now - self._latest_at:.3f} s"
            why = []
            if self.rsi_frames_unreadable:
                why.append(f"{self.rsi_frames_unreadable} unreadable frames, the last: {self._last_bad}")
            if self._framer_pending:
                why.append(f"{self._framer_pending} bytes received without a complete <Rob>")
        raise MotionRefused(
            f"RSI stream stale: no complete frame for {age} (more than {STALE_CYCLES} cycles of "
            f"{self.rsi_cycle_s * 1000:g} ms){': ' + '; '.join(why) if why else ''}; the move is not sent",
            code="rsi_stale",
            device=self.device,
        )

    # --- Robot protocol -------------------------------------------------------------------------------------

    def joints(self) -> tuple[float, ...]:
        self._require_connected()
        if self.rsi_sync is not None:  # simulation: the frame of now, freshness in controller time
            lag = self._synced_lag()
            with self._cond:
                self._raise_rsi_error()
                if lag is None or self._latest is None or lag > STALE_CYCLES:
                    raise DeviceTimeout(f"no current RSI frame (the latest is {lag} cycles behind the "
                                        "controller's)", device=self.device)  # fmt: skip
                return self._latest
        with self._cond:
            deadline = time.monotonic() + self.rsi_stale_s
            while self._latest is None and self._rsi_error is None:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                self._cond.wait(remaining)
            self._raise_rsi_error()
            if self._latest is None or self._latest_at is None:
                raise DeviceTimeout(f"no RSI frame with joint values within {self.rsi_stale_s} s", device=self.device)
            age = time.monotonic() - self._latest_at
            if age > self.rsi_stale_s:
                raise DeviceTimeout(
                    f"last RSI frame is {age:.2f} s old (limit {self.rsi_stale_s} s)", device=self.device
                )
            return self._latest

    def check_target(self, target_deg: Sequence[float]) -> tuple[float, ...]:
        """The target as a tuple, or MotionRefused (joint limits first, then the cell box)."""
        target = tuple(float(v) for v in target_deg)
        if len(target) != len(AXES):
            raise MotionRefused(
                f"target needs {len(AXES)} joint values, got {len(target)}", code="arity", device=self.device
            )
        for name, v, (lo, hi) in zip(AXES, target, self.joint_limits_deg, strict=True):
            if not math.isfinite(v) or not lo <= v <= hi:
                raise MotionRefused(
                    f"{name}={v} deg outside the joint limits [{lo}, {hi}] deg",
                    code="joint_limits",
                    device=self.device,
                )
        if self.cell_box_check is not None:
            reason = self.cell_box_check(target)
            if reason:
                raise MotionRefused(
                    f"target {target} leaves the cell box: {reason}", code="cell_box", device=self.device
                )
        return target

    def move(self, target_deg: tuple[float, ...], speed_override_pct: float) -> None:
        target = self.check_target(target_deg)
        speed = float(speed_override_pct)
        if not (math.isfinite(speed) and 1 <= round(speed) <= 100):
            raise MotionRefused(
                f"speed override {speed_override_pct} % outside 1..100 %", code="speed", device=self.device
            )
        self._require_connected()
        self._require_fresh_rsi()  # never move without the monitor
        command_id = self._next_id()
        self._send(Command(command_id, KIND_MOVE, target, int(round(speed))))
        state, stopped = self._await_state(command_id, guarded=True)
        if stopped:
            raise DeviceFault(f"move {command_id} to {target} stopped: {stopped}", code=ERR_STOPPED, device=self.device)
        if state.error:
            text = ERROR_TEXT.get(state.error, "controller fault")
            raise DeviceFault(f"move {command_id} to {target} failed: {text}", code=state.error, device=self.device)
        if not state.done:
            raise ProtocolError(
                f"move {command_id} acknowledged without Done and without an error code", device=self.device
            )

    def reset_faults(self) -> None:
        """Clear the controller's fault flags (after the operator acknowledged); DeviceFault if one is still
        active (e.g. the emergency stop not released)."""
        self._require_connected()
        command_id = self._next_id()
        self._send(Command(command_id, KIND_RESET))
        state, _ = self._await_state(command_id, guarded=False)
        if state.error:
            text = ERROR_TEXT.get(state.error, "controller fault")
            raise DeviceFault(f"fault reset {command_id}: {text} still active", code=state.error, device=self.device)

    def _next_id(self) -> int:
        return next(self._ids) % MAX_ID or next(self._ids)

    def _send(self, command: Command) -> None:
        eki = self._eki
        assert eki is not None
        try:
            eki.settimeout(self.io_timeout_s)
            eki.sendall(encode_command(command))
        except TimeoutError:
            raise DeviceTimeout(
                f"request {command.command_id} not sent within {self.io_timeout_s} s", device=self.device
            ) from None
        except OSError as exc:
            self._drop_eki()
            raise ConnectionLost(f"EKI send failed: {exc}", device=self.device) from exc

    def _guard(self) -> str | None:
        return None if self.motion_guard is None else self.motion_guard()

    def _await_state(self, command_id: int, guarded: bool) -> tuple[RobotState, str | None]:
        """The controller's answer to `command_id`, and why it was stopped (None if it was not). While
        `guarded`, the motion guard is polled every GUARD_S; when it names a reason the stop request is sent
        and the answer awaited io_timeout_s more (the robot brakes)."""
        eki = self._eki
        assert eki is not None
        deadline = time.monotonic() + self.move_timeout_s
        stopped: str | None = None
        next_guard = time.monotonic()
        while True:
            now = time.monotonic()
            if guarded and stopped is None and now >= next_guard:
                stopped = self._guard()
                next_guard = now + GUARD_S
                if stopped:
                    self._send(Command(command_id, KIND_STOP))
                    deadline = time.monotonic() + self.io_timeout_s
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                what = "stop" if stopped else "request"
                raise DeviceTimeout(
                    f"{what} {command_id} not acknowledged within "
                    f"{self.io_timeout_s if stopped else self.move_timeout_s} s",
                    device=self.device,
                )
            eki.settimeout(min(remaining, GUARD_S if guarded else _POLL_S * 4))
            try:
                data = eki.recv(_RECV_BYTES)
            except TimeoutError:
                continue
            except OSError as exc:
                self._drop_eki()
                raise ConnectionLost(f"EKI receive failed: {exc}", device=self.device) from exc
            if not data:
                self._drop_eki()
                raise ConnectionLost(
                    f"the controller closed the EKI connection during request {command_id}", device=self.device
                )
            try:
                docs = self._eki_framer.feed(data)
                states = [parse_state(doc) for doc in docs]
            except ProtocolError as exc:
                self._drop_eki()
                raise ProtocolError(f"EKI: {exc}", device=self.device) from None
            for state in states:
                if state.command_id == command_id or (state.command_id == 0 and state.error):
                    return state, stopped
                # an answer to an earlier request that timed out here: stale, skip it

    def wait_settled(self, tolerance_deg: float, window_s: float, timeout_s: float) -> tuple[float, ...]:
        """Joints from RSI frames arriving after the call that stay within tolerance_deg of the window's first
        frame for window_s of controller time; returns the last of them. The motion guard is polled every
        GUARD_S: a reason ends the wait (DeviceFault code ERR_STOPPED)."""
        if not (tolerance_deg > 0 and window_s >= 0 and timeout_s > 0):
            raise ValueError("tolerance_deg and timeout_s must be positive, window_s non-negative")
        self._require_connected()
        cycle = self.rsi_cycle_s
        real_deadline = time.monotonic() + timeout_s + self.rsi_stale_s
        if self.rsi_sync is not None:  # simulation: every frame due before the call is in
            self.rsi_sync(0)
        with self._cond:
            start_seq = next_seq = self._seq + 1
        anchor: tuple[float, ...] | None = None
        anchor_seq = 0
        next_guard = time.monotonic()
        while True:
            if time.monotonic() >= next_guard:
                reason = self._guard()
                if reason:
                    raise DeviceFault(f"settling stopped: {reason}", code=ERR_STOPPED, device=self.device)
                next_guard = time.monotonic() + GUARD_S
            with self._cond:
                self._raise_rsi_error()
                first_seq = self._frames[0][0] if self._frames else next_seq
                if next_seq < first_seq:  # fell behind the history: restart the window
                    next_seq, anchor = first_seq, None
                for seq, joints in itertools.islice(self._frames, next_seq - first_seq, None):
                    next_seq = seq + 1
                    if anchor is None or any(abs(a - b) > tolerance_deg for a, b in zip(joints, anchor, strict=True)):
                        anchor, anchor_seq = joints, seq
                    if (seq - anchor_seq) * cycle >= window_s - 1e-9:
                        return joints
                    if (seq - start_seq + 1) * cycle > timeout_s:
                        raise DeviceTimeout(
                            f"joints not settled within {tolerance_deg} deg over {window_s} s "
                            f"after {timeout_s} s of controller time",
                            device=self.device,
                        )
                remaining = real_deadline - time.monotonic()
                if remaining <= 0:
                    raise DeviceTimeout(
                        f"RSI frames stopped coming while waiting to settle ({timeout_s} s)",
                        device=self.device,
                    )
                if self.rsi_sync is None:
                    self._cond.wait(min(remaining, GUARD_S))
                    continue
                # simulation: the cycles the window still needs, GUARD_S of controller time at most per request
                have = 0 if anchor is None else next_seq - 1 - anchor_seq
                wanted = math.ceil(window_s / cycle - 1e-9) - have + (1 if anchor is None else 0)
            self.rsi_sync(max(1, min(wanted, math.ceil(GUARD_S / cycle))))

    def _require_connected(self) -> None:
        if self._eki is None or self._rsi is None:
            raise ConnectionLost("not connected (call connect() first)", device=self.device)

    def _drop_eki(self) -> None:
        eki, self._eki = self._eki, None
        if eki is not None:
            with contextlib.suppress(OSError):
                eki.close()

    def close(self) -> None:
        self._stop.set()
        threads, self._threads = self._threads, []
        rsi = self._rsi
        if rsi is not None and rsi is not self._rsi_listener:
            with contextlib.suppress(OSError):
                rsi.shutdown(socket.SHUT_RDWR)
        for thread in threads:
            thread.join(timeout=2.0)
        self._rsi = None
        self._drop_eki()
        for sock in (rsi, self._eki_listener, self._rsi_listener):
            if sock is not None:
                with contextlib.suppress(OSError):
                    sock.close()
        self._eki_listener = self._rsi_listener = None

    def __enter__(self) -> KukaKrc2:
        self.connect()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def _plain_ip(address: str) -> str:
    """An IPv4 address seen through an IPv6 socket (::ffff:a.b.c.d) as itself."""
    return address.removeprefix("::ffff:")
