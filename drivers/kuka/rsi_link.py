"""The RSI channel of a KR C2 (UDP by default, as on a KR C2; TCP available): the joint monitor.

The controller's ST_ETHERNET object connects to IP_NUMBER/PORT of its XML config (ros-industrial/kuka_experimental
kuka_rsi_hw_interface/krl/KR_C2/ros_rsi_ethernet.xml; trackcal's is configs/krc2/trackcal_rsi.xml, whose protocol and
passive flag are the defaults): trackcal listens, only the controller is served (drivers.kuka.peers).

- One thread receives the <Rob> frames and, unless passive (ONLYSEND TRUE: the controller expects no answer),
  answers each at once with <Sen>, zero corrections and the same IPOC, found without parsing the frame
  (drivers.kuka.rsi_codec.ipoc_of). That thread does nothing else: a second one parses the frames and keeps the
  latest AIPos (0.0001 deg), because a controller in answered mode stops the robot after more than
  eERXmaxLatePackages late answers.
- Whose frames count (issue 27): over TCP the session is the connection accepted from the controller. Over UDP
  it is the peer (address and port) of the KR C2's first frame after ST_ETHERNET, the one holding only an empty
  <IPOC/> (ros-industrial/kuka_experimental pull request #74, drivers.kuka.rsi_codec), from the controller's
  address. A trackcal started while the controller already streams (passive RSI keeps running between EKI
  connections, trackcal_eki.src) sees no such frame: it follows the first peer from the controller's address until
  an opener comes from it, once; a session begun with an opener is never given up. Datagrams from any other port
  and frames whose IPOC does not move forward (the controller's interpolation-cycle timestamp, one step per cycle:
  kuka_rsi_simulator in ros-industrial/kuka_experimental) are counted (`frames_foreign`, `frames_backwards`),
  logged once, never answered and never read. A restarted controller runs its KRL program from the top and ends
  the EKI connection: the campaign stops, `resume` connects again and takes the new stream.
- Freshness: a complete frame at most STALE_CYCLES cycles of rsi_cycle_s old (12 ms on a KR C2, 4 ms on a KR C4:
  the hardware file says which); `require_fresh` waits at most stale_s for one before it refuses a move. During a
  move or a settle, a stream silent for more than stale_s (`stale_for`) stops the robot (drivers.kuka.client).
- The frames are kept (FRAME_HISTORY of them, numbered) for settling windows judged in controller time: one frame
  = one interpolation cycle.
- Simulation only (`sync` given: `run --sim`, the mock controller in the same process on a virtual clock, where a
  standing robot's controller time passes only when somebody waits for it): before reading what the stream says
  while the robot stands (joints, the freshness check before a move, the settling window) the client asks the
  controller for its frame of now, or for the cycles its window still needs, and freshness is judged in controller
  time: the latest frame's IPOC at most STALE_CYCLES cycles behind the controller's (the IPOC counts milliseconds
  of controller time, kuka_rsi_simulator in ros-industrial/kuka_experimental). `frame_received` is what the
  lockstep controller waits on. With a passive controller the link then starts no thread (`pumped`): whoever
  looks at the stream (that wait, the client's reads) takes every datagram the socket holds through the steps the
  two threads take (issue 41: handing each frame through three threads was most of a simulated campaign's CPU).
  Without `sync` (a real controller, `trackcal mock`) nothing of this runs: every cycle's frame is received as it
  comes and freshness is wall time.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import queue
import select
import socket
import threading
import time
from collections import deque
from collections.abc import Callable

from trackcal.drivers.errors import ConnectionLost, DeviceError, DeviceTimeout, MotionRefused, ProtocolError
from trackcal.drivers.kuka.peers import ControllerPeers, accept_controller, bind
from trackcal.drivers.kuka.rsi_codec import (
    MAX_FRAME_BYTES,
    SenFrame,
    encode_sen,
    ipoc_of,
    parse_rob,
    rob_framer,
    rob_joints,
)
from trackcal.drivers.transport import time_left

POLL_S = 0.05  # socket timeout slice of the background threads
STALE_CYCLES = 5  # a move is refused when no complete RSI frame came for more than this many cycles
RSI_STALE = "rsi_stale"  # the code of a refused move, and of a move or settle stopped by a silent stream
FRAME_HISTORY = 8192  # RSI frames kept for settling windows (~98 s of 12 ms cycles)
_RECV_BYTES = 4096
_NEW_SESSION = b""  # from the answering to the monitor thread: the controller's session began, forget the stream

log = logging.getLogger(__name__)

RsiSync = Callable[[int], "int | None"]  # run n more cycles (0: none), the IPOC of the controller's last frame


class RsiLink:
    """The controller's RSI stream: answered (unless passive), parsed, the latest joints and their freshness."""

    def __init__(
        self,
        host: str,
        port: int,
        protocol: str,
        peers: ControllerPeers,
        *,
        passive: bool,
        cycle_s: float,
        stale_s: float,
        sync: RsiSync | None = None,
    ) -> None:
        if protocol not in ("tcp", "udp"):
            raise ValueError(f"rsi_protocol must be 'tcp' or 'udp', got {protocol!r}")
        self.host, self.port = host, int(port)
        self.protocol = protocol
        self.peers = peers
        self.device = peers.device
        self.passive = bool(passive)
        self.cycle_s = float(cycle_s)
        self.stale_s = stale_s
        self.sync = sync
        self._ipoc_step = max(1, round(self.cycle_s * 1000))  # IPOC: milliseconds of controller time

        self._listener: socket.socket | None = None  # TCP listener, or the bound UDP socket
        self._sock: socket.socket | None = None
        self._peer: tuple | None = None  # UDP: where the controller sends from

        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._inbox: queue.SimpleQueue = queue.SimpleQueue()  # (arrival time, frame) from answer to monitor
        self._handed = 0  # items the answering thread put in the inbox (written by that thread only)
        self._read_items = 0  # items the monitor thread took from it and read
        self._error: DeviceError | None = None
        self._frames: deque[tuple[int, tuple[float, ...]]] = deque(maxlen=FRAME_HISTORY)
        self._seq = 0
        self._latest: tuple[float, ...] | None = None
        self._latest_at: float | None = None
        self._latest_ipoc: int | None = None
        self._heard_at: float | None = None  # when the last frame with joints arrived (kept across a new session)
        self._last_bad = ""
        self._framer_pending = 0
        self.frames_answered = 0
        self.frames_unreadable = 0
        self.frames_foreign = 0  # UDP: from the controller's address but not its RSI session's peer
        self.frames_backwards = 0  # IPOC not after the last one read
        self._last_ipoc: int | None = None  # the answering thread's: the last IPOC taken
        self._logged: set[str] = set()
        self._opened = False  # UDP: the session began with the controller's first frame (else: a running stream)
        self._framer = rob_framer()  # TCP: the stream cut into frames
        self.pumped = False  # no threads: the frames are read by whoever asks (start, _pump)
        self.stop_requested = False  # KR C4 only: every answer carries <Stop>1</Stop> while set (drivers.krc4.client)
        self._pump_lock = threading.Lock()

    # --- address and connection -----------------------------------------------------------------------------

    @property
    def address(self) -> tuple[str, int]:
        self.listen()
        assert self._listener is not None
        return self._listener.getsockname()[:2]

    @property
    def connected(self) -> bool:
        return self._sock is not None

    @property
    def error(self) -> DeviceError | None:
        """What ended the stream (connection lost, unreadable TCP stream), None while it lives."""
        return self._error

    def listen(self) -> None:
        """Open the listening port, or bind the UDP socket (port 0 picks a free one; see address). Idempotent."""
        self.peers.resolve()
        if self._listener is None:
            kind = socket.SOCK_STREAM if self.protocol == "tcp" else socket.SOCK_DGRAM
            self._listener = bind(kind, self.host, self.port, "RSI", self.device)

    def accept(self, deadline: float, timeout_s: float) -> None:
        """The controller's RSI connection (TCP) or first datagram (UDP) before `deadline` (monotonic)."""
        self.listen()
        assert self._listener is not None
        host, port = self.address
        what = f"the KR C2's RSI {self.protocol.upper()} stream (ST_ETHERNET of trackcal_rsi.xml) on {host}:{port}"
        if self.protocol == "tcp":
            self._sock = accept_controller(self._listener, self.peers, deadline, timeout_s, what)
        else:
            self._first_datagram(deadline, timeout_s, what)

    def _first_datagram(self, deadline: float, timeout_s: float, what: str) -> None:
        sock = self._listener
        assert sock is not None

        def expired() -> DeviceTimeout:
            return DeviceTimeout(
                f"no datagram within {timeout_s} s: waited for {what}{self.peers.note()}", device=self.device
            )

        while True:
            sock.settimeout(time_left(deadline, expired))
            try:
                data, peer = sock.recvfrom(MAX_FRAME_BYTES + 1)
            except TimeoutError:
                continue
            except OSError as exc:
                raise ConnectionLost(f"UDP receive failed while waiting for {what}: {exc}", device=self.device) from exc
            if not self.peers.accepts(peer):
                continue
            self._peer, self._sock, self._opened = peer, sock, _is_opener(data)
            self._take(sock, data)
            return

    def start(self) -> None:
        """Start the answering and the monitor thread on the accepted stream; in lockstep with a passive controller
        (`pumped`) none: the frames are read by whoever asks (`_pump`)."""
        self._stop.clear()
        self._framer = rob_framer()
        self.pumped = self.sync is not None and self.passive
        if self.pumped:
            assert self._sock is not None
            self._sock.setblocking(False)  # a socket with a timeout would wait for data before the MSG_DONTWAIT read
            self._threads = []
            return
        self._threads = [
            threading.Thread(target=self._answer_loop, name="krc2-rsi-answer", daemon=True),
            threading.Thread(target=self._monitor_loop, name="krc2-rsi-monitor", daemon=True),
        ]
        for thread in self._threads:
            thread.start()

    def close(self) -> None:
        self._stop.set()
        threads, self._threads = self._threads, []
        sock = self._sock
        if sock is not None and sock is not self._listener:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
        for thread in threads:
            thread.join(timeout=2.0)
        self._sock = None
        for s in (sock, self._listener):
            if s is not None:
                with contextlib.suppress(OSError):
                    s.close()
        self._listener = None

    # --- the answering thread (nothing else) and the monitor thread -------------------------------------------

    def _answer_loop(self) -> None:
        sock = self._sock
        assert sock is not None
        sock.settimeout(POLL_S)
        try:
            while not self._stop.is_set():
                try:
                    self._receive(sock, 0)
                except TimeoutError:
                    continue
        except (DeviceError, OSError) as exc:
            self._receive_failed(exc)

    def _receive(self, sock: socket.socket, flags: int) -> None:
        """One read of the stream: its frames answered and handed on (`_take`). TimeoutError (or BlockingIOError
        with MSG_DONTWAIT) when nothing came; DeviceError when the stream ended or cannot be read."""
        if self.protocol == "tcp":
            data = sock.recv(_RECV_BYTES, flags)
            if not data:
                raise ConnectionLost("the controller closed the RSI connection", device=self.device)
            for doc in self._framer.feed(data):
                self._take(sock, doc)
            self._framer_pending = self._framer.pending
            return
        data, peer = sock.recvfrom(MAX_FRAME_BYTES + 1, flags)
        if peer == self._peer:
            self._take(sock, data)
        elif self.peers.accepts(peer):
            if not self._opened and _is_opener(data):  # the controller's session starts now
                self._peer, self._opened, self._last_ipoc = peer, True, None
                self._hand_on(time.monotonic(), _NEW_SESSION)
                self._take(sock, data)
            else:
                self._foreign(peer, f"not the peer of the controller's RSI session {self._peer}")

    def _receive_failed(self, exc: DeviceError | OSError) -> None:
        """The end of the stream, handed on as the answering thread's last item."""
        if isinstance(exc, DeviceError):
            if not exc.device:  # e.g. the framer's ProtocolError: name the device and the interface
                exc = type(exc)(f"RSI: {exc}", device=self.device)
            self._hand_on(time.monotonic(), exc)
        elif not self._stop.is_set():
            self._hand_on(time.monotonic(), ConnectionLost(f"RSI connection failed: {exc}", device=self.device))

    def _foreign(self, peer: tuple, why: str) -> None:
        """A datagram from the controller's address that is not its RSI session's: counted, logged once."""
        self.frames_foreign += 1
        self._log_once(f"foreign {peer[0]}:{peer[1]}", f"RSI frames from {peer[0]}:{peer[1]} ignored: {why}")

    def _log_once(self, key: str, text: str) -> None:
        if key not in self._logged:
            self._logged.add(key)
            log.warning("%s: %s", self.device, text)

    def _take(self, sock: socket.socket, doc: bytes) -> None:
        """Answer a frame at once (unless passive) and hand it to the monitor thread; a frame whose IPOC does not
        move forward is counted, logged once and dropped."""
        arrived = time.monotonic()
        ipoc = ipoc_of(doc)
        if ipoc is not None:
            if self._last_ipoc is not None and ipoc <= self._last_ipoc:
                self.frames_backwards += 1
                self._log_once("backwards", f"RSI frames ignored: IPOC {ipoc} not after {self._last_ipoc}")
                return
            self._last_ipoc = ipoc
        if not self.passive and ipoc is not None:
            answer = encode_sen(SenFrame(ipoc=ipoc, stop=self.stop_requested))
            if self.protocol == "tcp":
                sock.sendall(answer)
            else:
                sock.sendto(answer, self._peer)
            self.frames_answered += 1
        self._hand_on(arrived, doc)

    def _hand_on(self, arrived: float, item) -> None:
        """To the monitor thread; when `pumped` there is none and the asking thread reads the item at once, in
        the order received (issue 41: a queue between two steps of one thread cost a put and a get per frame)."""
        if self.pumped:
            self._read(arrived, item)
        else:
            self._handed += 1
            self._inbox.put((arrived, item))

    def _monitor_loop(self) -> None:
        while not self._stop.is_set():
            try:
                arrived, item = self._inbox.get(timeout=POLL_S)
            except queue.Empty:
                continue
            alive = self._read(arrived, item)
            with self._cond:
                self._read_items += 1
                self._cond.notify_all()
            if not alive:
                return

    def _read(self, arrived: float, item) -> bool:
        """One item of the answering thread's: a frame parsed and kept, a new session, or the stream's end;
        False when the stream ended."""
        if isinstance(item, DeviceError):
            self._set_error(item)
            return False
        if item is _NEW_SESSION:  # what the stream said before the controller's session is not the robot's
            with self._cond:
                self._frames.clear()
                self._latest = self._latest_at = self._latest_ipoc = None
            return True
        try:
            ipoc, joints = rob_joints(item)
        except ProtocolError as exc:
            if self.protocol == "tcp":  # a byte stream cannot be resynchronised
                self._set_error(ProtocolError(f"RSI: {exc}", device=self.device))
                return False
            with self._cond:  # one bad datagram is not the end of the stream: the stale check decides
                self.frames_unreadable += 1
                self._last_bad = str(exc)
            return True
        if ipoc is None:
            return True  # KR C2 first frame: nothing in it
        with self._cond:
            self._seq += 1
            self._frames.append((self._seq, joints))
            self._latest, self._latest_at, self._latest_ipoc = joints, arrived, ipoc
            self._heard_at = arrived
            self._cond.notify_all()
        return True

    def _pump(self) -> None:
        """Lockstep with a passive controller (`pumped`, simulation only): read every frame the socket holds now,
        in the caller's thread, through the same steps the two threads take one frame at a time (issue 41: three
        threads handing each of a move's frames on cost ~150 us of CPU a frame; the frames are read before anyone
        looks at the stream, and the controller waits for their delivery). A no-op otherwise."""
        if not self.pumped:
            return
        with self._pump_lock:
            sock = self._sock
            while sock is not None and self._error is None and not self._stop.is_set():
                try:
                    self._receive(sock, socket.MSG_DONTWAIT)
                except (BlockingIOError, TimeoutError):
                    break
                except (DeviceError, OSError) as exc:
                    self._receive_failed(exc)
                    break
            while True:
                try:
                    arrived, item = self._inbox.get_nowait()
                except queue.Empty:
                    return
                if not self._read(arrived, item):
                    return

    def _set_error(self, exc: DeviceError) -> None:
        with self._cond:
            if self._error is None:
                self._error = exc
            self._cond.notify_all()

    def _raise_error(self) -> None:
        if self._error is not None:
            raise self._error

    # --- lockstep (simulation) ------------------------------------------------------------------------------

    def frame_received(self, ipoc: int, timeout_s: float) -> bool:
        """Simulation hook (the lockstep mock controller waits on it): True once a frame with this IPOC or a later
        one was received, False after timeout_s or an RSI error."""
        deadline = time.monotonic() + timeout_s
        if self.pumped:  # read here, in the controller's thread
            while True:
                self._pump()
                with self._cond:
                    if self._latest_ipoc is not None and self._latest_ipoc >= ipoc:
                        return True
                    if self._error is not None or self._stop.is_set() or self._sock is None:
                        return False
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                with contextlib.suppress(OSError, ValueError):  # closed meanwhile: the next round says so
                    select.select([self._sock], [], [], min(remaining, POLL_S))
        with self._cond:
            while self._latest_ipoc is None or self._latest_ipoc < ipoc:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or self._error is not None or self._stop.is_set():
                    return False
                self._cond.wait(remaining)
            return True

    def _synced_lag(self) -> int | None:
        """Simulation (sync): the controller's stream brought up to its clock, how many cycles the latest frame
        received is behind the controller's last one (None: no frame received, or no answer from it)."""
        assert self.sync is not None
        current = self.sync(0)
        self._pump()
        with self._cond:
            if current is None or self._latest_ipoc is None:
                return None
            return max(0, current - self._latest_ipoc) // self._ipoc_step

    # --- what the stream says -------------------------------------------------------------------------------

    def require_fresh(self) -> None:
        """Return once a complete RSI frame is at most STALE_CYCLES cycles old; waits for one at most stale_s,
        then refuses (MotionRefused, code rsi_stale): no move is sent without a live monitor."""
        limit = STALE_CYCLES * self.cycle_s
        deadline = time.monotonic() + self.stale_s
        lag = self._synced_lag() if self.sync is not None else None
        with self._cond:
            self._raise_error()
            if self.sync is not None:  # simulation: in controller time
                if lag is not None and lag <= STALE_CYCLES:
                    return
                age = "ever" if lag is None else f"{lag} cycles"
            else:
                while True:
                    self._raise_error()
                    now = time.monotonic()
                    if self._latest_at is not None and now - self._latest_at <= limit:
                        return
                    if now >= deadline:
                        break
                    self._cond.wait(min(deadline - now, limit))
                age = "ever" if self._latest_at is None else f"{now - self._latest_at:.3f} s"
            why = []
            if self.frames_unreadable:
                why.append(f"{self.frames_unreadable} unreadable frames, the last: {self._last_bad}")
            if self.frames_foreign or self.frames_backwards:
                why.append(
                    f"{self.frames_foreign} frames from another peer and {self.frames_backwards} with an "
                    "IPOC going backwards ignored"
                )
            if self._framer_pending:
                why.append(f"{self._framer_pending} bytes received without a complete <Rob>")
        raise MotionRefused(
            f"RSI stream stale: no complete frame for {age} (more than {STALE_CYCLES} cycles of "
            f"{self.cycle_s * 1000:g} ms){': ' + '; '.join(why) if why else ''}; the move is not sent",
            code=RSI_STALE,
            device=self.device,
        )

    def stale_for(self) -> float | None:
        """Without sync (a real controller, `trackcal mock`): how long (wall seconds) no frame with joints arrived,
        when that is more than stale_s, else None: the stream went stale during a move or a settle. With sync the
        lockstep controller's own checks decide (`joints`, the settling window)."""
        if self.sync is not None:
            return None
        with self._cond:
            if self._heard_at is None:
                return None
            silent = time.monotonic() - self._heard_at
            return silent if silent > self.stale_s else None

    def joints(self) -> tuple[float, ...]:
        """The AIPos of the latest frame received before the call, if it is current (DeviceTimeout if not)."""
        if self.sync is not None:  # simulation: the frame of now, freshness in controller time
            lag = self._synced_lag()
            with self._cond:
                self._raise_error()
                if lag is None or self._latest is None or lag > STALE_CYCLES:
                    raise DeviceTimeout(
                        f"no current RSI frame (the latest is {lag} cycles behind the controller's)", device=self.device
                    )
                return self._latest
        with self._cond:
            deadline = time.monotonic() + self.stale_s
            # every frame received before the call, read: the answering thread answers a frame before the monitor
            # reads it, so a move answered by the controller after its dwell could leave the monitor some frames
            # behind on a loaded machine (a KR C2 loopback test read joint 1 at 8.78 deg after a move to 10 deg)
            handed = self._handed
            while (
                (self._latest is None or self._read_items < handed) and self._error is None and not self._stop.is_set()
            ):
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                self._cond.wait(remaining)
            self._raise_error()
            if self._latest is None or self._latest_at is None:
                raise DeviceTimeout(f"no RSI frame with joint values within {self.stale_s} s", device=self.device)
            age = time.monotonic() - self._latest_at
            if age > self.stale_s:
                raise DeviceTimeout(f"last RSI frame is {age:.2f} s old (limit {self.stale_s} s)", device=self.device)
            return self._latest

    @property
    def last_seq(self) -> int:
        """The number of the latest frame received (frames are numbered from 1)."""
        self._pump()
        with self._cond:
            return self._seq

    def frames_from(self, seq: int) -> tuple[int, list[tuple[int, tuple[float, ...]]]]:
        """(the oldest frame number still kept, the frames numbered `seq` or later); raises the stream's error."""
        self._pump()
        with self._cond:
            self._raise_error()
            first = self._frames[0][0] if self._frames else seq
            # from the newest end: a settling window asks for the last few of FRAME_HISTORY frames every few cycles
            newer = max(0, len(self._frames) - max(0, seq - first))
            return first, list(itertools.islice(reversed(self._frames), newer))[::-1]

    def wait_for_frame(self, seq: int, timeout_s: float) -> None:
        """Until frame number `seq` arrived, the stream failed or timeout_s passed."""
        self._pump()
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._seq < seq and self._error is None and not self._stop.is_set():
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return
                self._cond.wait(remaining)


def _is_opener(data: bytes) -> bool:
    """The KR C2's first RSI frame: a <Rob> holding only an empty <IPOC/> (drivers.kuka.rsi_codec)."""
    try:
        return parse_rob(data).ipoc is None
    except ProtocolError:
        return False
