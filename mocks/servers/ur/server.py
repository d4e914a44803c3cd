"""Sockets of the mock UR controller on one address: RTDE (30004), dashboard (29999), primary / secondary / real-time
script ports (30001 / 30002 / 30003) and the mock's own control port (CONTROL_PORT, no UR port: fault injection and
state for tests). One thread ticks the controller at 500 Hz of wall time; each connection has its reader thread.

RTDE (rtde_codec.py for the sources): a request is answered on its connection in the order received; the answer to
'S' is written before the first 'U' frame (both under the connection's write lock, `started` set after the
answer); frames go out at the recipe's frequency, counted on controller ticks (a frequency that does not divide 500
Hz gets the nearest ticks). A stream that is no RTDE (bad size, unknown type, a payload of the wrong size) closes
the connection, as the real controller drops a client it cannot parse.

Faults (control port or scheduled by the controller): `drop` closes every client connection at once (the controller
stays reachable), `unreachable S` closes them and refuses connections for S seconds (a controller gone from the
network for a while; the robot and its program go on), `stale on|off` stops / restarts the RTDE frames while the
connections stay open, `protective_stop`, `protective_stop_on_move N` (halfway through the N-th movej counted since
the mock started, or with its command when the arm already stands at its target), `safeguard_stop`,
`safeguard_reset`.
"""

from __future__ import annotations

import contextlib
import json
import re
import socket
import struct
import threading

from trackcal.drivers.interfaces import RealClock
from trackcal.mocks.servers.ur import dashboard, primary
from trackcal.mocks.servers.ur import rtde_codec as rc
from trackcal.mocks.servers.ur.controller import UrController
from trackcal.mocks.servers.ur.motion import TICK_S

RTDE_PORT, DASHBOARD_PORT, PRIMARY_PORT, SECONDARY_PORT, REALTIME_PORT = 30004, 29999, 30001, 30002, 30003
CONTROL_PORT = 30999  # the mock's own (not a UR port)
MAX_FREQUENCY = {True: 500.0, False: 125.0}  # e-Series (major version > 3) / CB3 (RTDE guide: 1..500 Hz; 1..125)
TICK_HZ = 1.0 / TICK_S
PRIMARY_PERIOD_S = 0.1  # robot state messages at 10 Hz on the primary / secondary interfaces (Client Interface doc)
MAX_CATCH_UP = 25  # ticks run at once when the process was descheduled (50 ms); beyond, controller time slips
SEND_TIMEOUT_S = 2.0
_PROGRAM_END = re.compile(r"^(?:def|sec)\s+\w+\s*\(\s*\)\s*:.*?^end\b[^\n]*(?:\n|$)", re.S | re.M)


class RtdeSession:
    def __init__(self, server: UrServer, sock: socket.socket) -> None:
        self.server, self.sock = server, sock
        self.wlock = threading.Lock()
        self.protocol = 1
        self.output: rc.Recipe | None = None
        self.inputs: dict[int, rc.Recipe] = {}
        self.reserved: set[str] = set()
        self.started = False
        self.closed = False
        self._next_output_id = 1
        self._next_input_id = 1
        self.frames_sent = 0
        with server.ctl.lock:
            self.messages_seen = server.ctl.message_count

    def send(self, data: bytes) -> None:
        with self.wlock:
            self.sock.sendall(data)

    def close(self) -> None:
        self.closed = True
        self.started = False
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        with contextlib.suppress(OSError):
            self.sock.close()

    def handle(self, command: int, payload: bytes) -> None:
        srv, ctl = self.server, self.server.ctl
        if command == rc.REQUEST_PROTOCOL_VERSION:
            if len(payload) != 2:
                raise rc.FrameError("protocol version request of the wrong size")
            (version,) = struct.unpack(">H", payload)
            ok = version in rc.PROTOCOL_VERSIONS
            if ok:
                self.protocol = version
            self.send(rc.pack_success(command, ok))
        elif command == rc.GET_URCONTROL_VERSION:
            self.send(rc.pack_version(*ctl.version))
        elif command == rc.CONTROL_PACKAGE_SETUP_OUTPUTS:
            if self.protocol >= 2:
                frequency, names = rc.parse_output_setup(payload)
            else:
                frequency, names = 125.0, rc.split_names(payload)
            types = tuple(rc.output_type(n) for n in names)
            top = MAX_FREQUENCY[ctl.version[0] > 3]
            ok = bool(names) and rc.NOT_FOUND not in types and 1.0 <= frequency <= top
            rid = 0
            if ok:
                rid, self._next_output_id = self._next_output_id, min(255, self._next_output_id + 1)
            recipe = rc.Recipe(rid, names, types, frequency)
            srv.recipes.append(("O", recipe))
            self.send(rc.pack(command, recipe.answer()))
            if ok:
                with self.wlock:
                    self.output = recipe
        elif command == rc.CONTROL_PACKAGE_SETUP_INPUTS:
            names = rc.split_names(payload)
            with srv.reserve_lock:
                taken = srv.reserved_inputs(self)
                types = tuple(
                    rc.IN_USE if (n in taken and rc.input_type(n) != rc.NOT_FOUND) else rc.input_type(n) for n in names
                )
                ok = bool(names) and rc.NOT_FOUND not in types and rc.IN_USE not in types and len(self.inputs) < 255
                rid = 0
                if ok:
                    rid = self._next_input_id
                    self._next_input_id += 1
                    self.reserved.update(names)
            recipe = rc.Recipe(rid, names, types)
            srv.recipes.append(("I", recipe))
            if ok:
                self.inputs[rid] = recipe
            self.send(rc.pack(command, recipe.answer()))
        elif command == rc.CONTROL_PACKAGE_START:
            ok = self.output is not None or bool(self.inputs)
            with self.wlock:  # the answer first, then frames (the tick thread takes the same lock)
                self.sock.sendall(rc.pack_success(command, ok))
                self.started = ok
        elif command == rc.CONTROL_PACKAGE_PAUSE:
            with self.wlock:
                self.started = False
                self.sock.sendall(rc.pack_success(command, True))
        elif command == rc.DATA_PACKAGE:
            if not payload:
                raise rc.FrameError("data package without a recipe id")
            recipe = self.inputs.get(payload[0])
            if recipe is None:
                self.send(rc.pack_text(f"unknown input recipe id {payload[0]}", "RTDE", rc.ERROR_MESSAGE))
                return
            ctl.write_inputs(rc.unpack_data(recipe, payload))
        elif command == rc.TEXT_MESSAGE:
            with ctl.lock:
                ctl.log.append(f"RTDE client message: {payload[:300]!r}")

    def due(self, tick: int) -> bool:
        """A frame of the output recipe belongs to controller tick `tick`."""
        f = self.output.frequency if self.output else 0.0
        return f > 0 and int(tick * f / TICK_HZ) != int((tick - 1) * f / TICK_HZ)


class UrServer:
    def __init__(
        self,
        ctl: UrController,
        host: str = "127.0.0.1",
        control_port: int = CONTROL_PORT,
        speed: float = 1.0,
        clock=None,
    ) -> None:
        """`clock` paces the ticks (now() / sleep(), default the wall clock, drivers.interfaces.RealClock); the
        controller itself counts ticks and reads no clock."""
        if not speed > 0:
            raise ValueError("speed must be positive")
        self.ctl, self.host = ctl, host
        self.clock = clock or RealClock()
        self.speed = float(speed)  # controller seconds per wall second
        self.ports = {
            "rtde": RTDE_PORT,
            "dashboard": DASHBOARD_PORT,
            "primary": PRIMARY_PORT,
            "secondary": SECONDARY_PORT,
            "realtime": REALTIME_PORT,
            "control": control_port,
        }
        self.rtde: list[RtdeSession] = []
        self.conns: dict[str, list[socket.socket]] = {k: [] for k in self.ports}
        self.reserve_lock = threading.Lock()
        self._listeners: dict[str, socket.socket] = {}
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.stale = False
        self.errors: list[str] = []
        self.frames = 0
        self.recipes: list[tuple[str, rc.Recipe]] = []  # every setup request answered ('O' | 'I', recipe)

    # ------------------------------------------------------------------ life
    def start(self) -> UrServer:
        try:
            for name in self.ports:
                self._listen(name)
        except OSError:
            self.stop()
            raise
        self._spawn(self._tick_loop)
        return self

    def _listen(self, name: str) -> None:
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((self.host, self.ports[name]))
            s.listen(8)
        except OSError:
            s.close()
            raise
        self._listeners[name] = s
        self._spawn(self._accept, s, name)

    def _spawn(self, fn, *args) -> None:
        t = threading.Thread(target=fn, args=args, daemon=True)
        t.start()
        self._threads = [th for th in self._threads if th.is_alive()] + [t]

    def _close_listeners(self, keep_control: bool) -> None:
        for name, s in list(self._listeners.items()):
            if keep_control and name == "control":
                continue
            del self._listeners[name]
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)  # wakes the thread blocked in accept (close alone does not, on Linux)
            with contextlib.suppress(OSError):
                s.close()

    def unreachable(self, seconds: float) -> None:
        """The controller vanishes from the network for `seconds`: every connection closed, connections refused,
        then it listens again (the robot and its program went on meanwhile)."""
        self._close_listeners(keep_control=True)
        self.drop_all()

        def back() -> None:
            for name in self.ports:
                if name not in self._listeners and not self._stop.is_set():
                    try:
                        self._listen(name)
                    except OSError as exc:
                        self.errors.append(f"cannot listen again on {name}: {exc}")

        timer = threading.Timer(seconds, back)
        timer.daemon = True
        timer.start()

    def stop(self) -> None:
        self._stop.set()
        self._close_listeners(keep_control=False)
        self.drop_all(control_too=True)

    def wait(self) -> None:
        self._stop.wait()

    def drop_all(self, control_too: bool = False) -> None:
        """Close every client connection (the control port's too only when the mock stops)."""
        for sess in list(self.rtde):
            sess.close()
        for name, socks in self.conns.items():
            if name == "control" and not control_too:
                continue
            for c in list(socks):
                with contextlib.suppress(OSError):
                    c.shutdown(socket.SHUT_RDWR)
                with contextlib.suppress(OSError):
                    c.close()

    def reserved_inputs(self, asking: RtdeSession) -> set[str]:
        out: set[str] = set()
        for sess in self.rtde:
            if sess is not asking and not sess.closed:
                out |= sess.reserved
        return out

    # ------------------------------------------------------------------ tick
    def _tick_loop(self) -> None:
        """Controller ticks at `speed` x 500 per wall second. At speed 1 every frame of every tick is sent (after a
        stall, the missed ones at once, up to MAX_CATCH_UP ticks; beyond, controller time slips). Faster than real
        time, each connection gets the newest frame due in each 2 ms of wall time (fewer frames, each the state of
        its own tick)."""
        period = TICK_S / self.speed if self.speed < 1 else TICK_S
        per_wake = max(1, round(self.speed))
        next_t = self.clock.now()
        while not self._stop.is_set():
            now = self.clock.now()
            if now < next_t:
                self.clock.sleep(next_t - now)
                continue
            late = int((now - next_t) / period) + 1
            if late > MAX_CATCH_UP:
                next_t = now - (MAX_CATCH_UP - 1) * period
                late = MAX_CATCH_UP
            next_t += late * period
            sessions = [s for s in self.rtde if s.started and not s.closed and s.output is not None]
            first, n = self.ctl.tick + 1, late * per_wake
            wanted: dict[int, list[RtdeSession]] = {}  # tick -> connections that get that tick's frame
            for sess in sessions:
                ticks = [t for t in range(first, first + n) if sess.due(t)]
                for t in ticks if per_wake == 1 else ticks[-1:]:
                    wanted.setdefault(t, []).append(sess)
            frames: list[tuple[RtdeSession, bytes]] = []
            for _ in range(n):
                self.ctl.step()
                if not self.stale:  # each frame holds the state of its own tick
                    frames.extend((sess, self._pack_frame(sess)) for sess in wanted.get(self.ctl.tick, ()))
            self._events()
            for sess, data in frames:
                self._send_frame(sess, data)

    def _pack_frame(self, sess: RtdeSession) -> bytes:
        recipe = sess.output
        assert recipe is not None
        return rc.pack_data(recipe, self.ctl.values(recipe.names))

    def _send_frame(self, sess: RtdeSession, data: bytes) -> None:
        try:
            with self.ctl.lock:  # each connection gets every message once, from its start on
                messages = [m for m in self.ctl.messages if m[0] > sess.messages_seen]
                sess.messages_seen = self.ctl.message_count
            with sess.wlock:
                if not sess.started or sess.closed:
                    return
                sess.sock.sendall(data)
            sess.frames_sent += 1
            self.frames += 1
            for _, text, level in messages:
                if sess.protocol >= 2:
                    sess.send(rc.pack_text(text, "Controller", level))
        except OSError:
            sess.close()

    def _events(self) -> None:
        with self.ctl.lock:
            events, self.ctl.events = self.ctl.events, []
        for what in events:
            self.fault(what)

    def fault(self, what: str) -> str:
        """Apply a fault by name; returns what was done (the control port's answer)."""
        ctl = self.ctl
        if what == "drop":
            self.drop_all()
        elif what.startswith("unreachable"):
            try:
                seconds = float(what.split()[1])
            except (IndexError, ValueError):
                return "unreachable needs seconds: unreachable 5"
            if not (0 <= seconds <= 3600):
                return "unreachable needs 0..3600 seconds"
            self.unreachable(seconds)
        elif what in ("stale", "stale on"):
            self.stale = True
        elif what == "stale off":
            self.stale = False
        elif what == "protective_stop":
            ctl.protective_stop("injected")
        elif what.startswith("protective_stop_on_move"):
            try:
                move = int(what.split()[1])
            except (IndexError, ValueError):
                return "protective_stop_on_move needs a move number: protective_stop_on_move 3"
            with ctl.lock:
                ctl.protective_stop_on_move = move
        elif what == "safeguard_stop":
            ctl.safeguard_stop()
        elif what == "safeguard_reset":
            ctl.safeguard_reset()
        else:
            return f"unknown fault {what!r}"
        return "ok"

    # ------------------------------------------------------------------ connections
    def _accept(self, listener: socket.socket, name: str) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = listener.accept()
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn.settimeout(SEND_TIMEOUT_S)
            handler = {"rtde": self._serve_rtde, "dashboard": self._serve_dashboard, "control": self._serve_control}
            self._spawn(handler.get(name, self._serve_script), conn, name)

    def _recv(self, conn: socket.socket) -> bytes:
        while not self._stop.is_set():
            try:
                return conn.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return b""
        return b""

    def _serve_rtde(self, conn: socket.socket, name: str) -> None:
        sess = RtdeSession(self, conn)
        self.rtde.append(sess)
        deframer = rc.Deframer()
        try:
            while not sess.closed:
                data = self._recv(conn)
                if not data:
                    break
                for command, payload in deframer.feed(data):
                    sess.handle(command, payload)
        except (rc.FrameError, struct.error, OSError) as exc:
            self.errors.append(f"RTDE: {exc}")
        finally:
            sess.close()
            with self.reserve_lock:
                self.rtde.remove(sess)

    def _lines(self, conn: socket.socket, name: str):
        self.conns[name].append(conn)
        buf = b""
        try:
            while True:
                data = self._recv(conn)
                if not data:
                    return
                buf += data
                while b"\n" in buf:
                    line, buf = buf.split(b"\n", 1)
                    yield line.decode("utf-8", "replace")
                if len(buf) > 65536:
                    return  # no line in 64 KiB: not a dashboard client
        finally:
            with contextlib.suppress(ValueError):
                self.conns[name].remove(conn)
            with contextlib.suppress(OSError):
                conn.close()

    def _serve_dashboard(self, conn: socket.socket, name: str) -> None:
        try:
            with contextlib.suppress(OSError):  # the client went away: nothing to answer
                conn.sendall((dashboard.GREETING + "\n").encode())
                for line in self._lines(conn, name):
                    with self.ctl.lock:
                        reply, close = dashboard.answer(line, self.ctl)
                    conn.sendall((reply + "\n").encode())
                    if close:
                        break
        finally:
            with contextlib.suppress(OSError):
                conn.close()

    def _serve_control(self, conn: socket.socket, name: str) -> None:
        with contextlib.suppress(OSError):  # the client went away: nothing to answer
            for line in self._lines(conn, name):
                cmd = line.strip()
                if cmd == "state":
                    recipes = [
                        {"kind": k, "id": r.id, "names": r.names, "types": r.types, "frequency": r.frequency}
                        for k, r in self.recipes[-64:]
                    ]
                    reply = json.dumps(
                        self.ctl.state()
                        | {"frames": self.frames, "stale": self.stale, "errors": self.errors[-10:], "recipes": recipes}
                    )
                elif cmd == "script":
                    with self.ctl.lock:
                        reply = json.dumps(self.ctl.last_script)
                elif cmd == "quit":
                    conn.sendall(b"ok\n")
                    self.stop()
                    return
                else:
                    reply = self.fault(cmd)
                conn.sendall((reply + "\n").encode())

    def _serve_script(self, conn: socket.socket, name: str) -> None:
        """Primary (30001), secondary (30002), real-time (30003): programs in; on 30001/30002 the version message
        and robot state messages out (the real-time port's 500 Hz packages are not emulated)."""
        self.conns[name].append(conn)
        if name in ("primary", "secondary"):
            self._spawn(self._primary_out, conn)
        text = ""
        try:
            while True:
                data = self._recv(conn)
                if not data:
                    break
                text += data.decode("utf-8", "replace")
                while (m := _PROGRAM_END.search(text)) is not None:
                    self.ctl.load_script(m.group(0))
                    text = text[m.end() :]
                if len(text) > 1 << 20:
                    text = ""
            if text.strip():
                self.ctl.load_script(text)
        finally:
            with contextlib.suppress(ValueError):
                self.conns[name].remove(conn)
            with contextlib.suppress(OSError):
                conn.close()

    def _primary_out(self, conn: socket.socket) -> None:
        try:
            with self.ctl.lock:
                ts = int(self.ctl.timestamp_us())
                cal = self.ctl.calibration
            conn.sendall(primary.version_message(self.ctl.version, ts) + primary.robot_state(cal))
            while not self._stop.wait(PRIMARY_PERIOD_S):
                conn.sendall(primary.robot_state(cal))
        except OSError:
            return
