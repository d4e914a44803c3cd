"""The digital twin follows the mock UR controller: an RTDE reader (in the process that holds the twin's World,
e.g. `trackcal mock`) that hands every frame's actual_q, in degrees, to a callback (World.robot_at), so the
tracker mock measures the arm where the controller process says it is.

    follower = JointFollower("127.0.0.5", world.robot_at).start()
    ...  # before a measurement: follower.fresh() waits for a frame sent after the call
    follower.stop()

It reconnects whenever the controller goes away (a dropped or unreachable controller, a restarted mock). Framing:
rtde_codec.py (protocol 2, one output recipe, 'S' answered before the first frame).
"""

from __future__ import annotations

import contextlib
import math
import socket
import struct
import threading
from collections.abc import Callable

from trackcal.mocks.servers.ur import rtde_codec as rc
from trackcal.mocks.servers.ur.server import RTDE_PORT

RECIPE = ("timestamp", "actual_q")
_RETRY_S = 0.05


class JointFollower:
    def __init__(
        self, host: str, on_joints: Callable[[tuple[float, ...]], None], frequency: float = 500.0, port: int = RTDE_PORT
    ) -> None:
        self.addr = (host, port)
        self.on_joints = on_joints
        self.frequency = float(frequency)
        self.frames = 0
        self.timestamp: float | None = None  # controller time of the last frame (s)
        self.q_deg: tuple[float, ...] | None = None
        self.errors: list[str] = []
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> JointFollower:
        self._thread = threading.Thread(target=self._run, name="ur-joint-follower", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._sock is not None:
            with contextlib.suppress(OSError):
                self._sock.shutdown(socket.SHUT_RDWR)
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    def fresh(self, timeout_s: float = 2.0) -> bool:
        """Wait for a frame that arrives after this call (the controller's state now, not a cycle ago)."""
        with self._cond:
            seen = self.frames
            return self._cond.wait_for(lambda: self.frames > seen, timeout=timeout_s)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self._follow()
            except (OSError, rc.FrameError, struct.error, UnicodeDecodeError, IndexError) as exc:
                self.errors.append(str(exc))
                del self.errors[:-20]
            self._stop.wait(_RETRY_S)

    def _follow(self) -> None:
        with socket.create_connection(self.addr, timeout=2.0) as s:
            self._sock = s
            deframer = rc.Deframer()
            backlog: list[tuple[int, bytes]] = []

            def ask(command: int, payload: bytes = b"") -> bytes:
                s.sendall(rc.pack(command, payload))
                while True:
                    for i, (cmd, body) in enumerate(backlog):
                        if cmd == command:
                            del backlog[: i + 1]
                            return body
                    data = s.recv(65536)
                    if not data:
                        raise OSError("controller closed the RTDE connection")
                    backlog.extend(deframer.feed(data))

            if ask(rc.REQUEST_PROTOCOL_VERSION, struct.pack(">H", 2)) != b"\x01":
                raise OSError("controller refused RTDE protocol 2")
            answer = ask(
                rc.CONTROL_PACKAGE_SETUP_OUTPUTS, struct.pack(">d", self.frequency) + ",".join(RECIPE).encode()
            )
            recipe = rc.Recipe(answer[0], RECIPE, tuple(answer[1:].decode().split(",")))
            if not recipe.valid:
                raise OSError(f"controller refused the recipe: {answer[1:].decode()}")
            if ask(rc.CONTROL_PACKAGE_START) != b"\x01":
                raise OSError("controller refused to start the RTDE stream")
            pending = [b for c, b in backlog if c == rc.DATA_PACKAGE]
            while not self._stop.is_set():
                for body in pending:
                    self._frame(recipe, body)
                try:
                    data = s.recv(65536)
                except TimeoutError:
                    continue
                if not data:
                    raise OSError("controller closed the RTDE connection")
                pending = [b for c, b in deframer.feed(data) if c == rc.DATA_PACKAGE]

    def _frame(self, recipe: rc.Recipe, body: bytes) -> None:
        if not body or body[0] != recipe.id:
            return
        values = rc.unpack_data(recipe, body)
        q = tuple(math.degrees(v) for v in values["actual_q"])  # type: ignore[union-attr]
        self.on_joints(q)
        with self._cond:
            self.timestamp = float(values["timestamp"])  # type: ignore[arg-type]
            self.q_deg = q
            self.frames += 1
            self._cond.notify_all()
