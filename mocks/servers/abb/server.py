"""The mock IRC5 controller as a whole: the controller (controller.AbbController) ticking every TICK_S / speed of wall
time on a thread, its Robot Web Services (rws_server.RwsServer), the EGM position stream (one EgmRobot datagram per
tick to the sensor's address, drivers.abb.egm_codec, when `egm` names one), and the mock's own control port (no ABB
port: a line protocol for tests and the twin):

    state                  -> one JSON line: the controller's snapshot
    fault KIND             -> ok (guardstop, emergencystop, motoroff, release, rapid_error)
    busy N                 -> ok: the next N RWS requests get 503
    egm off | egm on       -> ok: the EGM stream stops (the controller goes on) or sends again
    follow                 -> one line of six joint angles (deg, comma-separated) now and at every tick after
    quit                   -> ok, then the mock stops
"""

from __future__ import annotations

import contextlib
import json
import socket
import socketserver
import threading
import time

from trackcal.drivers.abb.egm_codec import EgmRobot, encode
from trackcal.mocks.servers.abb.controller import TICK_S, AbbController, RapidError
from trackcal.mocks.servers.abb.rws_server import RwsServer


class AbbServer:
    def __init__(
        self,
        controller: AbbController,
        flange,
        host: str = "127.0.0.1",
        port: int = 0,
        control_port: int = 0,
        seed: int = 0,
        speed: float = 1.0,
        egm: tuple[str, int] | None = None,
    ) -> None:
        self.controller = controller
        self.speed = speed
        self.egm = egm  # where the EGM position stream goes (the sensor's address), None: no stream
        self._egm_sock: socket.socket | None = None
        self.egm_paused = False  # the control port's `egm off`: the stream stops, the controller goes on
        self.rws = RwsServer(controller, flange, host, port, seed=seed)
        self.stopped = threading.Event()
        self.control = _ControlServer((host, control_port), self)
        self._threads: list[threading.Thread] = []

    @property
    def address(self) -> tuple[str, int]:
        return self.rws.address

    @property
    def control_address(self) -> tuple[str, int]:
        host, port = self.control.server_address[:2]
        return str(host), int(port)

    def start(self) -> AbbServer:
        self.rws.start()
        for target, name in ((self._tick, "abb-ticker"), (self.control.serve_forever, "abb-control")):
            t = threading.Thread(target=target, name=name, daemon=True)
            t.start()
            self._threads.append(t)
        return self

    def _tick(self) -> None:
        period = TICK_S / self.speed
        next_at = time.monotonic()
        while not self.stopped.is_set():
            self.controller.tick()
            if self.egm is not None and not self.egm_paused:
                self._send_egm()
            next_at += period
            delay = next_at - time.monotonic()
            if delay < -1.0:  # a paused process does not catch up a second of ticks at once
                next_at = time.monotonic()
            self.stopped.wait(max(0.0, delay))

    def _send_egm(self) -> None:
        """One EgmRobot datagram of the tick to the sensor (EGM position streaming: one message per 4 ms cycle)."""
        snap = self.controller.snapshot()
        msg = EgmRobot(
            seqno=snap["ticks"] & 0xFFFFFFFF,
            tm_ms=int(snap["ticks"] * TICK_S * 1000) & 0xFFFFFFFF,
            joints_deg=tuple(snap["q_deg"]),
            planned_deg=tuple(snap["planned_deg"]),
            motors_on=snap["ctrlstate"] == "motoron",
            rapid_running=snap["execution"] == "running",
        )
        if self._egm_sock is None:
            self._egm_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        with contextlib.suppress(OSError):  # nobody listening yet: a real controller's datagrams go unread too
            self._egm_sock.sendto(encode(msg), self.egm)

    def command(self, line: str) -> str:
        words = line.split()
        if not words:
            return "error: empty command"
        try:
            if words[0] == "state":
                return json.dumps(self.controller.snapshot())
            if words[0] == "fault" and len(words) == 2:
                self.controller.fault(words[1])
                return "ok"
            if words[0] == "egm" and len(words) == 2 and words[1] in ("on", "off"):
                self.egm_paused = words[1] == "off"
                return "ok"
            if words[0] == "busy" and len(words) == 2:
                self.rws.busy(int(words[1]))
                return "ok"
        except (RapidError, ValueError) as exc:
            return f"error: {exc}"
        return f"error: unknown command {line!r}"

    def stop(self) -> None:
        if self.stopped.is_set():
            return
        self.stopped.set()
        self.control.shutdown()
        self.control.server_close()
        self.rws.stop()

    def wait(self) -> None:
        self.stopped.wait()  # a signal (Ctrl-C, SIGTERM's handler) still interrupts it: a lock wait on POSIX


class _ControlServer(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, address, owner: AbbServer) -> None:
        self.owner = owner
        super().__init__(address, _ControlHandler)


class _ControlHandler(socketserver.StreamRequestHandler):
    def handle(self) -> None:
        owner: AbbServer = self.server.owner  # type: ignore[attr-defined]
        for raw in self.rfile:
            line = raw.decode("utf-8", "replace").strip()
            if line == "quit":
                self.wfile.write(b"ok\n")
                threading.Thread(target=owner.stop, daemon=True).start()
                return
            if line == "follow":
                self._follow(owner)
                return
            self.wfile.write((owner.command(line) + "\n").encode())

    def _follow(self, owner: AbbServer) -> None:
        lines: list[bytes] = []
        ready = threading.Condition()

        def push(q) -> None:
            with ready:
                lines.append((",".join(f"{v:.6f}" for v in q) + "\n").encode())
                ready.notify()

        push(owner.controller.snapshot()["q_deg"])
        owner.controller.followers.append(push)
        try:  # the reader going away (a broken pipe) ends the stream
            while not owner.stopped.is_set():
                with ready:
                    ready.wait_for(lambda: lines, timeout=0.2)
                    out, lines[:] = b"".join(lines), []
                if out:
                    self.wfile.write(out)
        except OSError:
            return
        finally:
            with contextlib.suppress(ValueError):
                owner.controller.followers.remove(push)
            with contextlib.suppress(OSError):
                self.request.shutdown(socket.SHUT_RDWR)
