"""Where trackcal listens for the KR C2, and whom it serves: the controller named in the hardware file, only.

On the KR C2 both interfaces have the controller as the network *client*: trackcal listens on two ports and the
robot connects (Ethernet KRL XML 1.2: external system = server, ros-industrial/kuka_experimental pull request #205's
PC side accepts the controller's connection; RSI: ST_ETHERNET connects to IP_NUMBER/PORT of its XML config,
kuka_experimental kuka_rsi_hw_interface/krl/KR_C2/ros_rsi_ethernet.xml).

Trust: both listeners bind to the configured local address (the hardware config names it: there is no 0.0.0.0
default), a TCP connection from any other address than `controller_host`'s is closed at once (counted in
`refused`) and the accept goes on until the controller comes, a UDP datagram from elsewhere is ignored; each
channel serves one connection, the first from the controller, and accepts no other while it lasts.
"""

from __future__ import annotations

import contextlib
import socket

from trackcal.drivers.errors import ConnectionLost, DeviceTimeout
from trackcal.drivers.transport import time_left


class ControllerPeers:
    """The controller's addresses (resolved once) and every peer refused because it is not the controller."""

    def __init__(self, controller_host: str, device: str) -> None:
        self.controller_host = controller_host
        self.device = device
        self.refused: list[tuple[str, int]] = []  # (address, port) of connections and datagrams refused
        self._ips: frozenset[str] | None = None

    def resolve(self) -> None:
        """Resolve the controller's name (once); ConnectionLost if it does not resolve."""
        if self._ips is not None:
            return
        try:
            infos = socket.getaddrinfo(self.controller_host, None)
        except OSError as exc:
            raise ConnectionLost(
                f"cannot resolve the controller's address {self.controller_host}: {exc}", device=self.device
            ) from exc
        self._ips = frozenset(plain_ip(info[4][0]) for info in infos)

    def accepts(self, peer: tuple) -> bool:
        """True for the controller; anyone else is recorded in `refused`."""
        self.resolve()
        assert self._ips is not None
        if plain_ip(peer[0]) in self._ips:
            return True
        self.refused.append((peer[0], peer[1]))
        return False

    def note(self) -> str:
        """What was refused, for a timeout's message ("" when nobody was)."""
        if not self.refused:
            return ""
        who = ", ".join(sorted({a for a, _ in self.refused}))
        return f" (refused {len(self.refused)} from {who}: not the controller {self.controller_host})"


def bind(kind: int, host: str, port: int, what: str, device: str) -> socket.socket:
    """A socket bound to host:port (TCP: listening for one connection)."""
    try:
        infos = socket.getaddrinfo(host, port, type=kind)
        family, _, _, _, addr = infos[0]
        sock = socket.socket(family, kind)
    except OSError as exc:
        raise ConnectionLost(f"cannot resolve {what} address {host}:{port}: {exc}", device=device) from exc
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(addr)
        if kind == socket.SOCK_STREAM:
            sock.listen(1)
    except OSError as exc:
        sock.close()
        raise ConnectionLost(f"cannot listen for {what} on {host}:{port}: {exc}", device=device) from exc
    return sock


def accept_controller(
    listener: socket.socket, peers: ControllerPeers, deadline: float, timeout_s: float, what: str
) -> socket.socket:
    """The first connection from the controller before `deadline` (monotonic); any other is closed at once."""

    def expired() -> DeviceTimeout:
        return DeviceTimeout(
            f"no connection within {timeout_s} s: waited for {what}{peers.note()}", device=peers.device
        )

    while True:
        listener.settimeout(time_left(deadline, expired))
        try:
            conn, peer = listener.accept()
        except TimeoutError:
            continue
        except OSError as exc:
            raise ConnectionLost(f"accept failed while waiting for {what}: {exc}", device=peers.device) from exc
        if peers.accepts(peer):
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            return conn
        with contextlib.suppress(OSError):
            conn.close()


def plain_ip(address: str) -> str:
    """An IPv4 address seen through an IPv6 socket (::ffff:a.b.c.d) as itself."""
    return address.removeprefix("::ffff:")
