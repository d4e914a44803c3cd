"""The mock KR C2's socket ends: the EKI channel and the RSI stream, as the controller's side opens them.

Like the real controller it is the network *client*: it connects to the EKI (and, over TCP, the RSI) port where
trackcal listens (Ethernet KRL XML 1.2: EKX_Open of the channel configs/krc2/TrackcalEki.xml declares, as in
ros-industrial/kuka_experimental pull request #205; RSI: ST_ETHERNET to IP_NUMBER/PORT of configs/krc2/
trackcal_rsi.xml). Garbage from the peer never raises: it is recorded in `errors` and the connection it came on is
dropped (a stream cannot be resynchronised). No thread here: the controller's thread calls everything.
"""

from __future__ import annotations

import contextlib
import select
import socket
from collections.abc import Callable

from trackcal.drivers.errors import ProtocolError
from trackcal.drivers.kuka.eki_codec import COMMAND_ROOT, XmlStreamFramer
from trackcal.drivers.kuka.rsi_codec import MAX_FRAME_BYTES, RobFrame, encode_rob, parse_sen, sen_framer


def _shut(sock: socket.socket) -> None:
    with contextlib.suppress(OSError):
        sock.shutdown(socket.SHUT_RDWR)
    with contextlib.suppress(OSError):
        sock.close()


def open_stream(addr: tuple[str, int]) -> socket.socket | OSError:
    """One attempt at the controller's TCP connection to trackcal (no Nagle: one document per segment), or why
    it failed."""
    try:
        sock = socket.create_connection(addr, timeout=1.0)
    except OSError as exc:
        return exc
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    sock.settimeout(None)
    return sock


class EkiEnd:
    """The controller's end of the EKI channel (TCP): documents in, <RobotState> documents out."""

    def __init__(self, addr: tuple[str, int], errors: list[str]) -> None:
        self.addr = addr
        self.errors = errors
        self.sock: socket.socket | None = None
        self._framer = XmlStreamFramer(COMMAND_ROOT)

    @property
    def connected(self) -> bool:
        return self.sock is not None

    def connect(self) -> OSError | None:
        """One attempt (EKX_Open); the failure, if it failed."""
        sock = open_stream(self.addr)
        if isinstance(sock, OSError):
            return sock
        self.sock = sock
        self._framer = XmlStreamFramer(COMMAND_ROOT)
        return None

    def receive(self, timeout: float) -> list[bytes]:
        """The complete <RobotCommand> documents that arrived within timeout (wall seconds; 0: what is there)."""
        sock = self.sock
        assert sock is not None
        try:
            readable, _, _ = select.select([sock], [], [], timeout)
            if not readable:
                return []
            data = sock.recv(4096)
        except OSError as exc:
            self.close(f"EKI receive failed: {exc}")
            return []
        if not data:
            self.close(None)  # trackcal went away: the program closes the channel and opens it again
            return []
        try:
            return self._framer.feed(data)
        except ProtocolError as exc:
            self.close(f"EKI: unreadable stream, connection dropped: {exc}")
            return []

    def send(self, data: bytes) -> None:
        if self.sock is None:
            return
        try:
            self.sock.sendall(data)
        except OSError as exc:
            self.close(f"EKI send failed: {exc}")

    def close(self, why: str | None) -> None:
        sock, self.sock = self.sock, None
        if sock is None:
            return
        if why:
            self.errors.append(why)
        _shut(sock)


class RsiEnd:
    """The controller's end of the RSI stream: a <Rob> per cycle out, the <Sen> answers in (unless passive).

    `on_lost()` runs when the stream ends on an error (not on a plain close): without its RSI partner the
    controller stops the robot."""

    def __init__(
        self, addr: tuple[str, int], protocol: str, sen_type: str, errors: list[str], on_lost: Callable[[], None]
    ) -> None:
        self.addr = addr
        self.protocol = protocol
        self.sen_type = sen_type
        self.errors = errors
        self.on_lost = on_lost
        self.sock: socket.socket | None = None
        self._framer = sen_framer()
        self.answer = None  # the last <Sen> answered in time (its AK corrections: a KR C4 applies them)

    @property
    def connected(self) -> bool:
        return self.sock is not None

    def connect_tcp(self) -> OSError | None:
        """One attempt at the TCP stream; the failure, if it failed. The KR C2 sends an empty IPOC first."""
        sock = open_stream(self.addr)
        if isinstance(sock, OSError):
            return sock
        self.sock = sock
        self._framer = sen_framer()
        self.send(encode_rob(RobFrame(ipoc=None), tcp=True))  # KR C2: empty IPOC first
        return None

    def open_udp(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect(self.addr)
        self.send(encode_rob(RobFrame(ipoc=None), tcp=False))  # KR C2: empty IPOC first

    def send(self, data: bytes) -> bool:
        if self.sock is None:
            return False
        try:
            self.sock.sendall(data) if self.protocol == "tcp" else self.sock.send(data)
            return True
        except ConnectionRefusedError:
            return self.protocol == "udp"  # nobody listens (yet) on the UDP port: the datagram is lost
        except OSError as exc:
            self.close(f"RSI send failed: {exc}")
            return False

    def await_answer(self, ipoc: int, deadline: float, now: Callable[[], float]) -> bool:
        """True once the <Sen> answer with this IPOC came before `deadline` (on the wall clock `now`)."""
        while True:
            sock = self.sock
            if sock is None:
                return False
            remaining = deadline - now()
            if remaining <= 0:
                return False
            try:
                readable, _, _ = select.select([sock], [], [], remaining)
                if not readable:
                    continue
                data = sock.recv(4096 if self.protocol == "tcp" else MAX_FRAME_BYTES + 1)
            except ConnectionRefusedError:
                return False  # UDP: nobody listens; the answer is late
            except OSError as exc:
                self.close(f"RSI receive failed: {exc}")
                return False
            if self.protocol == "tcp":
                if not data:
                    self.close("trackcal closed the RSI connection")
                    return False
                try:
                    docs = self._framer.feed(data)
                except ProtocolError as exc:
                    self.close(f"RSI: unreadable answer stream, connection dropped: {exc}")
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
                    ok, self.answer = True, sen  # answers with another IPOC are stale answers to late packets: ignored
            if ok:
                return True

    def close(self, why: str | None) -> None:
        sock, self.sock = self.sock, None
        if sock is None:
            return
        if why:
            self.errors.append(why)
        _shut(sock)
        if why is not None:
            self.on_lost()
