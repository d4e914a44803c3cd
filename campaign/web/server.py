"""The page's server: uvicorn on a thread beside the campaign, bound before the session is made (a port in use
is one line and exit 2, before anything moves), with the URL (and off loopback its token, also as a QR code) on
the console."""

from __future__ import annotations

import contextlib
import html
import io
import ipaddress
import re
import secrets
import socket
import threading
from collections.abc import Callable, Sequence
from pathlib import Path

import segno
import uvicorn
from rich.text import Text

from trackcal.calib.model.cell import Cell
from trackcal.campaign.cells.operator import FirstAnswer
from trackcal.campaign.engine.steps import Step
from trackcal.campaign.errors import InputError
from trackcal.campaign.session.store import SessionStore
from trackcal.campaign.web.app import build_app
from trackcal.campaign.web.hub import Hub, PageOperator
from trackcal.campaign.web.state import plan_view
from trackcal.drivers.errors import DeviceError

DEFAULT_PORT = 8470  # `--web-port`'s default: a fixed port, so that a page left open finds `trackcal resume` again
LOOPBACK = "127.0.0.1"


def is_loopback(host: str) -> bool:
    """127.0.0.1 and ::1 (and `localhost`) only: any other address, 127.0.0.2 included, needs the token."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host) in (ipaddress.ip_address("127.0.0.1"), ipaddress.ip_address("::1"))
    except ValueError:
        return False


def _reachable_address() -> str:
    """The address other machines reach this one at (the route to a TEST-NET-1 address; no packet is sent)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.1", 9))
            return s.getsockname()[0]
        except OSError:
            return "127.0.0.1"


class WebPage:
    """`trackcal run|resume|replay --operator web`: binds now; `attach` serves a session's campaign; `operator`
    makes the prompt shared between the console (and the cell's button) and the page; `finish` shows the report's
    outcome; `close` ends it. `say` prints a line on the console as it is (a rich Text for colour)."""

    def __init__(
        self,
        host: str = LOOPBACK,
        port: int = DEFAULT_PORT,
        say: Callable[[str | Text], None] = print,
        out: Callable[[str], None] = print,
    ) -> None:
        self.host, self.say, self.out = host, say, out
        self.loopback = is_loopback(host)
        self.token = None if self.loopback else secrets.token_urlsafe(18)
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self.sock = socket.socket(family, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.sock.bind((host, port))
            self.sock.listen(64)
        except (OSError, OverflowError) as exc:
            self.sock.close()
            why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            raise InputError(f"--web-host {host} --web-port {port}: cannot listen there ({why})") from None
        self.port = self.sock.getsockname()[1]
        self.hub: Hub | None = None
        self.server: uvicorn.Server | None = None
        self.thread: threading.Thread | None = None
        self.closing = threading.Event()
        self.report_dir: Path | None = None

    @property
    def url(self) -> str:
        shown = _reachable_address() if self.host in ("0.0.0.0", "::") else self.host
        shown = f"[{shown}]" if ":" in shown else shown
        return f"http://{shown}:{self.port}/" + (f"?token={self.token}" if self.token else "")

    def attach(self, store: SessionStore, cell: Cell, steps: Sequence[Step]) -> Hub:
        """Serve the campaign of `store` (its events so far and every document from now on)."""
        steps = list(steps)
        # a replay's prompts are answered by its recording: the page only watches it
        self.hub = Hub(store, plan_view(cell, steps) | {"replay": store.meta().get("mode") == "replay"})
        self.report_dir = store.directory / "report"
        hosts = {f"{h}:{self.port}" for h in ("127.0.0.1", "localhost", "[::1]")} if self.loopback else None
        app = build_app(self.hub, steps, self.token, hosts, self.report_dir, self.closing, self.say)
        config = uvicorn.Config(app, log_level="error", access_log=False, lifespan="off", timeout_graceful_shutdown=2)
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(
            target=self.server.run, kwargs={"sockets": [self.sock]}, name="operator-page", daemon=True
        )
        self.hub.alive = lambda: self.thread is not None and self.thread.is_alive() and not self.closing.is_set()
        self.thread.start()
        self.announce()
        return self.hub

    def announce(self) -> None:
        self.say(Text.assemble(("operator's page", "bold"), f": {self.url}"))
        if self.token:
            qr = io.StringIO()
            segno.make(self.url, error="m").terminal(out=qr, compact=True)
            self.out(qr.getvalue())
            self.say("(anyone with this URL can answer the prompts: show it only to the cell's operators)")

    def operator(self, base, console, cellio=None) -> FirstAnswer:
        """The prompt offered to the cell's operator (`base`: the button, or the console in a cell without a PLC),
        the console (when it is not `base` already) and the page; the door and E-stop read while it waits."""
        ops = [base] + ([console] if console is not None and console is not base else []) + [PageOperator(self.hub)]
        return FirstAnswer(ops, self.say, watch=None if cellio is None else self._watch(cellio))

    def _watch(self, cellio):
        def watch() -> None:
            values = {}
            try:
                values["door_closed"] = bool(cellio.door_closed())
                status = getattr(cellio, "read_status", None)
                if status is not None:
                    values["estop_ok"] = bool(status().estop_ok)
            except DeviceError:  # the page shows "unknown"; the engine's own checks decide
                values = {"door_closed": None, "estop_ok": None}
            self.hub.set_live(**values)

        return watch

    def finish(self, report: Path | None, note: str = "") -> None:
        """The campaign was analysed: the report's outcome sentence and a link to it (no report: `note` says why)."""
        if self.hub is None:
            return
        sentence = note
        if report is not None and report.is_file():
            m = re.search(r"<p class='verdict' id='verdict'>(.*?)</p>", report.read_text(errors="replace"), re.S)
            sentence = html.unescape(m.group(1)) if m else ""
        link = None if report is None else f"/report/{report.name}"
        self.hub.set_live(outcome={"sentence": sentence, "report": link})

    def close(self) -> None:
        self.closing.set()
        if self.hub is not None:
            with self.hub.lock:
                listeners = list(self.hub._listeners)
            for push in listeners:
                push("close", None)
        if self.server is not None:
            self.server.should_exit = True
        if self.thread is not None:
            self.thread.join(timeout=5.0)
        with contextlib.suppress(OSError):
            self.sock.close()
