"""The EKI channel of a KR C4 / KR C5 (TCP): the controller serves, trackcal connects.

EthernetKRL 3.x on KSS 8 lets either side serve; configs/krc4/TrackcalEki.xml says EXTERNAL/TYPE Client (the
external system is the client, as in ros-industrial/kuka_experimental kuka_eki_hw_interface/krl/
EkiHwInterface.xml) and INTERNAL/PORT the controller's port. So, unlike the KR C2 (drivers.kuka.eki_link, where
trackcal listens), trackcal connects to the controller named in the hardware file, and to nobody else; the
documents and their handling are the KR C2's (the same EkiLink, only the connection is opened the other way).
A dropped connection is opened again by the next accept(): the KRL program clears and reopens its channel when
trackcal goes away (configs/krc4/trackcal_eki.src)."""

from __future__ import annotations

import socket
import time

from trackcal.drivers.errors import DeviceTimeout
from trackcal.drivers.kuka.eki_codec import STATE_ROOT, XmlStreamFramer
from trackcal.drivers.kuka.eki_link import EkiLink
from trackcal.drivers.kuka.peers import ControllerPeers

RETRY_S = 0.1  # between connection attempts while the controller's channel is not open yet


class EkiClientLink(EkiLink):
    """EkiLink with trackcal as the TCP client of the controller's EKI server (controller_host:port)."""

    def __init__(self, port: int, peers: ControllerPeers, *, io_timeout_s: float) -> None:
        super().__init__(peers.controller_host, port, peers, io_timeout_s=io_timeout_s)

    @property
    def address(self) -> tuple[str, int]:
        """The controller's EKI server."""
        return self.host, self.port

    def listen(self) -> None:
        """Nothing to open on this side (the controller serves); resolves the controller's name."""
        self.peers.resolve()

    def accept(self, deadline: float, timeout_s: float) -> None:
        """Connect to the controller's channel before `deadline` (monotonic), retrying while it is not open (the
        program not started yet, or between its EKI_Clear and EKI_Open)."""
        self.listen()
        last: OSError | None = None
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeout(
                    f"no EKI connection within {timeout_s} s to the KR C4 at {self.host}:{self.port} "
                    f"(start trackcal_eki on the controller; last error: {last})",
                    device=self.device,
                )
            try:
                sock = socket.create_connection((self.host, self.port), timeout=min(remaining, 2.0))
            except OSError as exc:
                last = exc
                time.sleep(min(RETRY_S, max(0.0, deadline - time.monotonic())))
                continue
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock.settimeout(self.io_timeout_s)
            self._sock, self._framer = sock, XmlStreamFramer(STATE_ROOT)
            return

    def close(self) -> None:
        self.drop()
