"""The mock KR C4's socket ends, where they differ from the KR C2's (mocks/servers/kuka/links.py):

- EKI: the controller serves (configs/krc4/TrackcalEki.xml, EXTERNAL/TYPE Client: the external system connects):
  a listening socket on the controller's address; one client at a time, as an EthernetKRL channel serves one
  connection; `connect()` takes a waiting client, if any (the controller's thread never blocks on it).
- RSI: UDP to IP_NUMBER/PORT (configs/krc4/trackcal_rsi_ethernet.xml), without the KR C2's empty-IPOC opener
  (that frame is a KR C2 RSI 2 quirk, ros-industrial/kuka_experimental pull request #74), and the root written
  `<Rob Type="KUKA">` as RSI 3+ writes it (the KR C2's kuka_rsi_simulator writes TYPE; no reader looks at it:
  rsi_state.h reads only child elements).
"""

from __future__ import annotations

import contextlib
import select
import socket

from trackcal.drivers.kuka.eki_codec import COMMAND_ROOT, XmlStreamFramer
from trackcal.mocks.servers.kuka.links import EkiEnd, RsiEnd


class EkiServerEnd(EkiEnd):
    """The controller's EKI server: listens on addr (port 0: a free one, see `addr`)."""

    def __init__(self, addr: tuple[str, int], errors: list[str]) -> None:
        super().__init__(addr, errors)
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind(addr)
        self.listener.listen(1)
        self.addr = self.listener.getsockname()[:2]

    def connect(self) -> OSError | None:
        """Take the waiting client, if any (EKI_Open serves it); else why not."""
        try:
            readable, _, _ = select.select([self.listener], [], [], 0.0)
            if not readable:
                return ConnectionRefusedError("no EKI client waiting")
            sock, _ = self.listener.accept()
        except OSError as exc:
            return exc
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(None)
        self.sock, self._framer = sock, XmlStreamFramer(COMMAND_ROOT)
        return None

    def shut(self) -> None:
        """The controller is switched off: the server goes too."""
        self.close(None)
        with contextlib.suppress(OSError):
            self.listener.close()


class RsiUdpEnd(RsiEnd):
    """The RSI ETHERNET object of KSS 8: UDP, no opener, `<Rob Type="KUKA">`."""

    def open_udp(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect(self.addr)

    def send(self, data: bytes) -> bool:
        return super().send(data.replace(b'<Rob TYPE="KUKA">', b'<Rob Type="KUKA">', 1))
