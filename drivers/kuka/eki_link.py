"""The EKI channel of a KR C2 (TCP): trackcal listens, the controller's trackcal_eki program connects.

Ethernet KRL XML 1.2 has the external system as the server: ros-industrial/kuka_experimental pull request #205
("KRC2 port for kuka_eki_hw_interface"), the KR C2 EKI program trackcal's follows, accepts the controller's
connection on the PC side; the channel's documents are the ones configs/krc2/TrackcalEki.xml and TrackcalEki+.xml
declare (drivers.kuka.eki_codec). One <RobotCommand> per request (a move, a stop of the running move, a reset of
the fault flags); the KRL program answers moves and resets with one <RobotState> whose echoed ID is the
acknowledgement (configs/krc2/trackcal_eki.src).

Only the controller named in the hardware file is served (drivers.kuka.peers). A failed send or receive, the
controller closing the channel or bytes that do not parse drop the connection (a stream cannot be resynchronised);
the next accept() takes the controller's new connection (trackcal_eki.src closes and reopens its channel).
"""

from __future__ import annotations

import contextlib
import socket

from trackcal.drivers.errors import ConnectionLost, DeviceTimeout, ProtocolError
from trackcal.drivers.kuka.eki_codec import (
    STATE_ROOT,
    Command,
    RobotState,
    XmlStreamFramer,
    encode_command,
    parse_state,
)
from trackcal.drivers.kuka.peers import ControllerPeers, accept_controller, bind
from trackcal.drivers.transport import receive

_RECV_BYTES = 4096


class EkiLink:
    """The TCP channel to the KRL program: send a RobotCommand, await its RobotState."""

    def __init__(self, host: str, port: int, peers: ControllerPeers, *, io_timeout_s: float) -> None:
        self.host, self.port = host, int(port)
        self.peers = peers
        self.device = peers.device
        self.io_timeout_s = io_timeout_s
        self._listener: socket.socket | None = None
        self._sock: socket.socket | None = None
        self._framer = XmlStreamFramer(STATE_ROOT)

    @property
    def address(self) -> tuple[str, int]:
        self.listen()
        assert self._listener is not None
        return self._listener.getsockname()[:2]

    @property
    def connected(self) -> bool:
        return self._sock is not None

    def listen(self) -> None:
        """Open the listening port (port 0 picks a free one; see address). Idempotent."""
        self.peers.resolve()
        if self._listener is None:
            self._listener = bind(socket.SOCK_STREAM, self.host, self.port, "EKI", self.device)

    def accept(self, deadline: float, timeout_s: float) -> None:
        """Take the controller's connection before `deadline` (monotonic; timeout_s is what it stands for)."""
        self.listen()
        assert self._listener is not None
        host, port = self.address
        what = f"the KR C2's EKI connection (EKX_Open of trackcal_eki) on {host}:{port}"
        self._sock = accept_controller(self._listener, self.peers, deadline, timeout_s, what)
        self._sock.settimeout(self.io_timeout_s)

    def send(self, command: Command) -> None:
        sock = self._sock
        assert sock is not None
        try:
            sock.settimeout(self.io_timeout_s)
            sock.sendall(encode_command(command))
        except TimeoutError:
            raise DeviceTimeout(
                f"request {command.command_id} not sent within {self.io_timeout_s} s", device=self.device
            ) from None
        except OSError as exc:
            self.drop()
            raise ConnectionLost(f"EKI send failed: {exc}", device=self.device) from exc

    def receive_state(self, command_id: int, timeout_s: float) -> RobotState | None:
        """The controller's answer to `command_id` (or an unsolicited fault report, ID 0) if it comes within
        timeout_s, else None. Answers to earlier requests that timed out here are stale: skipped."""
        sock = self._sock
        assert sock is not None
        data = receive(
            sock,
            _RECV_BYTES,
            timeout_s,
            device=self.device,
            failed="EKI receive failed",
            closed=f"the controller closed the EKI connection during request {command_id}",
            drop=self.drop,
        )
        if data is None:
            return None
        try:
            docs = self._framer.feed(data)
            states = [parse_state(doc) for doc in docs]
        except ProtocolError as exc:
            self.drop()
            raise ProtocolError(f"EKI: {exc}", device=self.device) from None
        for state in states:
            if state.command_id == command_id or (state.command_id == 0 and state.error):
                return state
        return None

    def drop(self) -> None:
        """Close the connection (the listener stays: the controller connects again)."""
        sock, self._sock = self._sock, None
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.close()

    def close(self) -> None:
        self.drop()
        listener, self._listener = self._listener, None
        if listener is not None:
            with contextlib.suppress(OSError):
                listener.close()
