"""The mock controller's Robot Web Services 1.0 (RobotWare 6) HTTP server over an AbbController.

As a RobotWare 6 controller answers (ABB, "Application Manual - Robot Web Services", 3HAC050973-001,
developercenter.robotstudio.com/api/rwsApi/; the page of each resource in the table below):
- HTTP digest authentication (RFC 7616, MD5, qop=auth; the manual's sample calls are `curl --digest -u "Default
  User":robotics`): a request without a session cookie or a valid digest gets 401 with a fresh challenge; an
  authenticated one opens a session and gets the cookies `-http-session-` and `ABBCX`, which then stand for the
  digest; `GET /logout` ends the session; at most MAX_SESSIONS sessions at once (the manual: 70), more get 503;
- `?json=1` selects JSON (`application/json`: `_links`, `_embedded._state` items with `_type`, `_title` and the
  fields), otherwise XHTML (`<li class=_type title=_title>` with one `<span class=field>` per field);
- an error carries `_embedded.status` {code, msg}: 400 a bad request or a refused action, 404 an unknown resource,
  405 a method the resource does not take, 503 busy (the control port's `busy N` makes the next N requests get it).
The return codes in error answers are the mock's own (negative, as RobotWare's are), not RobotWare's table.
"""

from __future__ import annotations

import hashlib
import html
import json
import math
import socket
import threading
import urllib.parse
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import cast

import numpy as np
from scipy.spatial.transform import Rotation

from trackcal.calib.model.kinematics import Kinematics
from trackcal.drivers.abb.program import MODULE, TASK
from trackcal.drivers.abb.rws import DEFAULT_PASSWORD, DEFAULT_USER, parse_challenge
from trackcal.mocks.servers.abb.controller import AbbController, RapidError

REALM = "validusers@robapi.abb"  # the realm RobotWare 6 names in its digest challenge
MAX_SESSIONS = 70
ERR_BAD_REQUEST, ERR_NOT_FOUND, ERR_REFUSED, ERR_BUSY = -1001, -1002, -1003, -1004  # the mock's own codes
# ROS-Industrial's abb_irb120_support (urdf/irb120_3_58_macro.xacro): tool0 is link_6 turned by +90 deg about y, the
# frame ABB calls tool0 (z out of the flange)
TOOL0 = Rotation.from_euler("y", 90, degrees=True)


class Answer(Exception):
    """An HTTP answer other than 200 with state items: `status`, and for an error its code and message."""

    def __init__(self, status: int, code: int = 0, msg: str = "") -> None:
        super().__init__(msg)
        self.status, self.code, self.msg = status, code, msg


def item(type_: str, heading: str, /, **fields) -> dict:
    """One state item: its `_type` (the XHTML li's class), `_title` and fields."""
    return {"_type": type_, "_title": heading, **fields}


class RwsResources:
    """The resources: path -> items (GET) or an action (POST), on the controller."""

    def __init__(self, controller: AbbController, flange: Callable, serial: str, system: str) -> None:
        self.c = controller
        self.flange = flange  # q_deg -> (R 3x3, origin mm): the controller's own (nominal) model of the arm
        self.serial, self.system = serial, system

    def get(self, path: str, query: dict[str, str]) -> list[dict]:
        c = self.c
        snap = c.snapshot()
        if path == "rw/panel/ctrlstate":
            return [item("pnl-ctrlstate", "ctrlstate", ctrlstate=snap["ctrlstate"])]
        if path == "rw/panel/opmode":
            return [item("pnl-opmode", "opmode", opmode=snap["opmode"])]
        if path == "rw/rapid/execution":
            return [item("rap-execution", "execution", ctrlexecstate=snap["execution"], cycle="forever")]
        if path == "rw/rapid/tasks":
            running = "started" if snap["execution"] == "running" else "stopped"
            return [
                item(
                    "rap-task-li",
                    f"RAPID/{TASK}",
                    name=TASK,
                    type="normal",
                    taskstate="linked",
                    excstate=running,
                    active="On",
                    motiontask="TRUE",
                )
            ]
        if path == "rw/motionsystem/mechunits/ROB_1/jointtarget":
            axes = {f"rax_{i + 1}": f"{v:.6f}" for i, v in enumerate(snap["q_deg"])}
            return [item("ms-jointtarget", "ROB_1", **axes, **{f"eax_{k}": "9E+09" for k in "abcdef"})]
        if path == "rw/motionsystem/mechunits/ROB_1/robtarget":
            return [self._robtarget(snap["q_deg"], query)]
        if path in ("rw/elog/0", "rw/elog/0/"):
            return self._elog()
        if path == "rw/system":
            return [
                item(
                    "sys-system-li",
                    "system",
                    major="6",
                    minor="15",
                    build="0",
                    revision="1",
                    sub_revision="0",
                    title="RobotWare",
                    type="RobotWare",
                    description="Controller Software",
                    name=self.system,
                    rwversion="6.15.01.00",
                    sysid="{" + self.serial + "}",
                    rwversionname="6.15.01.00",
                )
            ]
        if path == "ctrl/identity":
            return [
                item(
                    "ctrl-identity-info",
                    "identity",
                    **{"ctrl-name": self.system, "ctrl-type": "Real Controller", "ctrl-id": self.serial},
                )
            ]
        name = self._symbol(path)
        try:
            return [item("rap-data", name, value=c.read(name))]
        except KeyError:
            raise Answer(400, ERR_NOT_FOUND, f"RAPID symbol {name} not found") from None

    def _symbol(self, path: str) -> str:
        """The variable a symbol path names (with or without the module), or 404."""
        prefix = f"rw/rapid/symbol/data/RAPID/{TASK}/"
        if not path.startswith(prefix):
            raise Answer(404, ERR_NOT_FOUND, f"no resource {path}")
        parts = path[len(prefix) :].split("/")
        if len(parts) == 2 and parts[0] == MODULE:
            return parts[1]
        if len(parts) == 1 and parts[0]:
            return parts[0]
        raise Answer(400, ERR_NOT_FOUND, f"RAPID symbol {'/'.join(parts)} not found")

    def _robtarget(self, q_deg, query: dict[str, str]) -> dict:
        if query.get("tool", "tool0") != "tool0" or query.get("wobj", "wobj0") != "wobj0":
            raise Answer(400, ERR_REFUSED, "only tool0 and wobj0 are defined")
        if query.get("coordinate", "Base") not in ("Base", "World"):
            raise Answer(400, ERR_REFUSED, "coordinate Base or World")
        r, o = self.flange(q_deg)
        w, x, y, z = _quaternion(Rotation.from_matrix(r) * TOOL0)
        cf = [math.floor(math.radians(q_deg[i]) / (math.pi / 2)) for i in (0, 3, 5)]
        fields = {
            "x": f"{o[0]:.6g}",
            "y": f"{o[1]:.6g}",
            "z": f"{o[2]:.6g}",
            "q1": f"{w:.7g}",
            "q2": f"{x:.7g}",
            "q3": f"{y:.7g}",
            "q4": f"{z:.7g}",
            "cf1": str(cf[0]),
            "cf4": str(cf[1]),
            "cf6": str(cf[2]),
            "cfx": "0",
        }
        return item("ms-robtargets", "ROB_1", **fields, **{f"eax{k}": "9E+09" for k in "abcdef"})

    def _elog(self) -> list[dict]:
        out = []
        with self.c.lock:
            entries = list(self.c.elog)
        for seq, msgtype, code, title, t in reversed(entries):  # newest first, as the FlexPendant lists them
            stamp = _stamp(t)
            out.append(
                item(
                    "elog-message-li",
                    f"/rw/elog/0/{seq}",
                    msgtype=str(msgtype),
                    code=str(code),
                    tstamp=stamp,
                    title=title,
                    desc=f"The system is in the {title}.",
                    conseqs="",
                    causes="",
                    actions="",
                    argc="0",
                )
            )
        return out

    def post(self, path: str, query: dict[str, str], form: dict[str, str]) -> None:
        action = query.get("action", "")
        c = self.c
        try:
            if path == "rw/panel/ctrlstate" and action == "setctrlstate":
                c.set_ctrlstate(form.get("ctrl-state", ""))
            elif path == "rw/rapid/execution" and action == "start":
                c.start()
            elif path == "rw/rapid/execution" and action == "stop":
                c.stop()
            elif path == "rw/rapid/execution" and action == "resetpp":
                c.resetpp()
            elif path.startswith(f"rw/rapid/tasks/{TASK}") and action in ("activate", "deactivate"):
                pass  # one motion task, always active
            elif path.startswith("rw/rapid/symbol/data/") and action == "set":
                name = self._symbol(path)
                if "value" not in form:
                    raise Answer(400, ERR_REFUSED, "value is required")
                c.write(name, form["value"])
            else:
                raise Answer(404 if action == "" else 400, ERR_NOT_FOUND, f"no action {action!r} on {path}")
        except RapidError as exc:
            raise Answer(400, ERR_REFUSED, str(exc)) from None
        except KeyError as exc:
            raise Answer(400, ERR_NOT_FOUND, f"RAPID symbol {exc.args[0]} not found") from None


def _quaternion(rotation: Rotation) -> tuple[float, float, float, float]:
    x, y, z, w = rotation.as_quat()
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    return float(w), float(x), float(y), float(z)


def _stamp(t: float) -> str:
    """An elog time stamp in RobotWare's layout ('%Y-%m-%d T  %H:%M:%S', as abb-robot-client parses it), from a fixed
    boot time (2026-01-01 08:00:00) plus the controller time: deterministic."""
    s = int(t) + 8 * 3600
    return f"2026-01-01 T  {s // 3600 % 24:02d}:{s // 60 % 60:02d}:{s % 60:02d}"


class Sessions:
    """Digest challenges and the sessions they open (deterministic tokens: a function of the seed and a count)."""

    def __init__(self, seed: int, user: str = DEFAULT_USER, password: str = DEFAULT_PASSWORD) -> None:
        self.seed, self.user, self.password = seed, user, password
        self.lock = threading.Lock()
        self.count = 0
        self.nonces: set[str] = set()
        self.open: dict[str, str] = {}  # -http-session- -> ABBCX

    def _token(self, kind: str) -> str:
        self.count += 1
        return hashlib.sha256(f"{self.seed}:{kind}:{self.count}".encode()).hexdigest()[:32]

    def challenge(self) -> str:
        with self.lock:
            nonce = self._token("nonce")
            self.nonces.add(nonce)
            del_count = len(self.nonces) - 1000
            for old in list(self.nonces)[: max(0, del_count)]:
                self.nonces.discard(old)
        return f'Digest realm="{REALM}", nonce="{nonce}", qop="auth", algorithm=MD5'

    def known(self, cookies: dict[str, str]) -> bool:
        with self.lock:
            s = cookies.get("-http-session-")
            return s is not None and self.open.get(s) == cookies.get("ABBCX")

    def authenticate(self, method: str, header: str) -> bool:
        fields = parse_challenge(header)
        if not fields or fields.get("username") != self.user or fields.get("realm") != REALM:
            return False
        with self.lock:
            if fields.get("nonce") not in self.nonces:
                return False

        def h(text: str) -> str:
            return hashlib.md5(text.encode()).hexdigest()  # RFC 7616's MD5 digest

        ha1, ha2 = h(f"{self.user}:{REALM}:{self.password}"), h(f"{method}:{fields.get('uri', '')}")
        if fields.get("qop") == "auth":
            expected = h(f"{ha1}:{fields['nonce']}:{fields.get('nc', '')}:{fields.get('cnonce', '')}:auth:{ha2}")
        else:
            expected = h(f"{ha1}:{fields['nonce']}:{ha2}")
        return fields.get("response") == expected

    def new(self) -> tuple[str, str] | None:
        """A new session's cookies, or None when MAX_SESSIONS are open."""
        with self.lock:
            if len(self.open) >= MAX_SESSIONS:
                return None
            session, abbcx = self._token("session"), self._token("abbcx")
            self.open[session] = abbcx
            return session, abbcx

    def end(self, cookies: dict[str, str]) -> None:
        with self.lock:
            self.open.pop(cookies.get("-http-session-", ""), None)


class RwsServer:
    """The HTTP server on (host, port) in a thread: `start()`, `stop()`, `address`; `busy(n)`: the next n requests
    get 503."""

    def __init__(
        self, controller: AbbController, flange: Callable, host: str = "127.0.0.1", port: int = 0, seed: int = 0
    ) -> None:
        self.resources = RwsResources(
            controller, flange, serial=f"120-{500000 + seed % 100000:06d}", system=f"IRB120_{seed}"
        )
        self.sessions = Sessions(seed)
        self._busy = 0
        self._busy_lock = threading.Lock()
        self.requests = 0
        self.httpd = _Httpd((host, port), self)
        self._thread: threading.Thread | None = None

    @property
    def address(self) -> tuple[str, int]:
        host, port = self.httpd.server_address[:2]
        return str(host), int(port)

    def busy(self, n: int) -> None:
        with self._busy_lock:
            self._busy = n

    def take_busy(self) -> bool:
        with self._busy_lock:
            self.requests += 1
            if self._busy > 0:
                self._busy -= 1
                return True
            return False

    def start(self) -> RwsServer:
        self._thread = threading.Thread(
            target=self.httpd.serve_forever, kwargs={"poll_interval": 0.05}, name="abb-rws", daemon=True
        )
        self._thread.start()
        return self

    def stop(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()
        if self._thread is not None:
            self._thread.join(timeout=5.0)


class _Httpd(ThreadingHTTPServer):
    daemon_threads = True

    def __init__(self, address, owner: RwsServer) -> None:
        self.owner = owner
        super().__init__(address, _Handler)


class _Handler(BaseHTTPRequestHandler):
    """One connection's requests, answered for the RwsServer that owns the HTTP server."""

    protocol_version = "HTTP/1.1"
    server_version = "Appweb/4"  # RobotWare 6's RWS runs on the Appweb embedded web server

    @property
    def owner(self) -> RwsServer:
        return cast(_Httpd, self.server).owner

    def setup(self) -> None:
        super().setup()
        # headers and body leave in two writes: without TCP_NODELAY the body waits for the client's delayed ACK
        # (Nagle's algorithm, RFC 896, against RFC 1122's delayed ACK: 40 ms on Linux)
        self.connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def log_message(self, format, *args) -> None:  # noqa: A002 (the base class's name)
        """Nothing: a controller keeps no access log on the console the tests and `trackcal mock` print to."""

    def do_GET(self) -> None:  # noqa: N802 (http.server's name)
        self._serve("GET")

    def do_POST(self) -> None:  # noqa: N802
        self._serve("POST")

    def do_PUT(self) -> None:  # noqa: N802
        self._serve("PUT")

    def do_DELETE(self) -> None:  # noqa: N802
        self._serve("DELETE")

    def _serve(self, method: str) -> None:
        url = urllib.parse.urlsplit(self.path)
        query = dict(urllib.parse.parse_qsl(url.query))
        as_json = query.pop("json", "0") == "1"
        path = url.path.strip("/")
        length = int(self.headers.get("Content-Length") or 0)
        body = self.rfile.read(length) if length else b""
        cookies = _cookies(self.headers.get("Cookie", ""))
        set_cookies: list[str] = []
        try:
            if self.owner.take_busy():
                raise Answer(503, ERR_BUSY, "controller busy")
            set_cookies = self._authorize(method, cookies)
            items = self._dispatch(method, path, query, body, cookies)
        except Answer as answer:
            self._error(answer, as_json, set_cookies)
            return
        except Exception as exc:  # a bug of the mock: an answer all the same, never a dropped connection
            answer = Answer(500, ERR_REFUSED, f"internal error: {type(exc).__name__}: {exc}")
            self._error(answer, as_json, set_cookies)
            return
        self._send(200 if items is not None else 204, items, path, as_json, set_cookies)

    def _authorize(self, method: str, cookies: dict[str, str]) -> list[str]:
        if self.owner.sessions.known(cookies):
            return []
        if not self.owner.sessions.authenticate(method, self.headers.get("Authorization", "")):
            raise Answer(401, 0, "authentication required")
        opened = self.owner.sessions.new()
        if opened is None:
            raise Answer(503, ERR_BUSY, f"too many sessions (at most {MAX_SESSIONS})")
        cookies.update({"-http-session-": opened[0], "ABBCX": opened[1]})
        return [f"-http-session-={opened[0]}; path=/; httponly", f"ABBCX={opened[1]}; path=/; httponly"]

    def _dispatch(self, method, path, query, body, cookies) -> list[dict] | None:
        if path == "logout" and method == "GET":
            self.owner.sessions.end(cookies)
            return None
        if method == "GET":
            return self.owner.resources.get(path, query)
        if method == "POST":
            form = dict(urllib.parse.parse_qsl(body.decode("utf-8", "replace")))
            self.owner.resources.post(path, query, form)
            return None
        raise Answer(405, ERR_REFUSED, f"{method} not allowed on {path}")

    def _error(self, answer: Answer, as_json: bool, set_cookies: list[str]) -> None:
        extra = {"WWW-Authenticate": self.owner.sessions.challenge()} if answer.status == 401 else {}
        if answer.status == 401:
            payload, ctype = b"", "text/html"
        elif as_json:
            doc = {"_links": {"base": {"href": "/"}}, "_embedded": {"status": {"code": answer.code, "msg": answer.msg}}}
            payload, ctype = json.dumps(doc).encode(), "application/json"
        else:
            payload = _xhtml("error", [item("status", "status", code=str(answer.code), msg=answer.msg)])
            ctype = "application/xhtml+xml"
        self._write(answer.status, payload, ctype, set_cookies, extra)

    def _send(self, status, items, path, as_json, set_cookies) -> None:
        if items is None:
            self._write(status, b"", "text/plain", set_cookies, {})
            return
        base = "/" + path.rsplit("/", 1)[0] + "/" if "/" in path else "/"
        if as_json:
            doc = {"_links": {"base": {"href": base}}, "_embedded": {"_state": items}}
            self._write(status, json.dumps(doc).encode(), "application/json", set_cookies, {})
        else:
            self._write(status, _xhtml(path, items), "application/xhtml+xml", set_cookies, {})

    def _write(self, status, payload, ctype, set_cookies, extra) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(payload)))
        for line in set_cookies:
            self.send_header("Set-Cookie", line)
        for k, v in extra.items():
            self.send_header(k, v)
        self.end_headers()
        if payload and self.command != "HEAD":
            self.wfile.write(payload)


def _cookies(header: str) -> dict[str, str]:
    out = {}
    for part in header.split(";"):
        name, _, value = part.strip().partition("=")
        if name:
            out[name] = value
    return out


def _xhtml(title: str, items: list[dict]) -> bytes:
    """The XHTML page of state items, as RWS 1.0 writes them without json=1."""
    lis = []
    for it in items:
        spans = "".join(
            f'<span class="{html.escape(k)}">{html.escape(str(v))}</span>'
            for k, v in it.items()
            if not k.startswith("_")
        )
        lis.append(f'<li class="{html.escape(it["_type"])}" title="{html.escape(it["_title"])}">{spans}</li>')
    text = (
        '<?xml version="1.0" encoding="utf-8"?><html xmlns="http://www.w3.org/1999/xhtml"><head><title>'
        f'{html.escape(title)}</title></head><body><div class="state"><ul>{"".join(lis)}</ul></div></body></html>'
    )
    return text.encode("utf-8")


def flange_of(chain) -> Callable:
    """q_deg -> (R, origin mm) of the chain's last joint frame: the controller's nominal model."""
    kin = Kinematics(chain, [])

    def flange(q_deg):
        r, o = kin.end_frames(np.radians(np.asarray(q_deg, dtype=float))[None, :])
        return r[0], o[0]

    return flange
