"""A self-contained HTML page printed to PDF by Debian's headless chromium, with a footer on every page (the page's id
and "page N of M").

Chromium's print-to-PDF ignores CSS @page margin boxes, and its command line (`--print-to-pdf`) prints the file's
URL and the date in the margins. So chromium is driven through the DevTools protocol over a pipe
(`--remote-debugging-pipe`: commands as NUL-terminated JSON on its file descriptor 3, answers and events on 4; no
port, no dependency): open the page, wait for its load event, then `Page.printToPDF` with `displayHeaderFooter` and a
footer template whose `pageNumber` and `totalPages` chromium fills in.
"""

from __future__ import annotations

import base64
import contextlib
import html
import json
import os
import select
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

from trackcal.calib.io.files import write_bytes
from trackcal.campaign.errors import InputError

# off the network and out of any profile (the page is self-contained: its images are data URIs)
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--remote-debugging-pipe",
)
TIMEOUT_S = 180.0  # the whole print, on a loaded 2-core machine; a page of the ISO report takes seconds
A4_IN = (8.27, 11.69)
MARGIN_IN = 0.55


class PdfError(InputError):
    """The page could not be printed (no chromium, or chromium failed)."""


def chromium_path() -> str:
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found is None:
        raise PdfError("--pdf needs Debian's chromium (apt-get install chromium): it is not on PATH")
    return found


def _footer(text: str) -> str:
    return (
        "<div style='font-size:8px;font-family:sans-serif;width:100%;margin:0 0.55in;display:flex;"
        f"justify-content:space-between'><span>{html.escape(text)}</span><span>page <span class='pageNumber'>"
        "</span> of <span class='totalPages'></span></span></div>"
    )


class _Pipe:
    """The DevTools protocol over chromium's debugging pipe: send a command, wait for its answer or an event."""

    def __init__(self, proc: subprocess.Popen, write_fd: int, read_fd: int, deadline: float):
        self.proc, self.write_fd, self.read_fd, self.deadline = proc, write_fd, read_fd, deadline
        self.buf, self.n = b"", 0

    def send(self, method: str, params: dict | None = None, session: str | None = None) -> int:
        self.n += 1
        msg = {"id": self.n, "method": method, "params": params or {}, **({"sessionId": session} if session else {})}
        os.write(self.write_fd, json.dumps(msg).encode() + b"\0")
        return self.n

    def wait(self, *, answer: int | None = None, event: str | None = None) -> dict:
        while True:
            while b"\0" not in self.buf:
                left = self.deadline - time.monotonic()
                if left <= 0 or not select.select([self.read_fd], [], [], left)[0]:
                    raise PdfError(f"chromium did not print the page within {TIMEOUT_S:.0f} s")
                chunk = os.read(self.read_fd, 1 << 20)
                if not chunk:
                    raise PdfError(f"chromium ended while printing the page (exit code {self.proc.poll()})")
                self.buf += chunk
            raw, self.buf = self.buf.split(b"\0", 1)
            msg = json.loads(raw)
            if answer is not None and msg.get("id") == answer:
                if "error" in msg:
                    raise PdfError(f"chromium refused to print: {msg['error'].get('message', msg['error'])}")
                return msg["result"]
            if event is not None and msg.get("method") == event:
                return msg

    def call(self, method: str, params: dict | None = None, session: str | None = None) -> dict:
        return self.wait(answer=self.send(method, params, session))


def html_to_pdf(page: str, path: Path, footer: str) -> Path:
    """Print the self-contained HTML `page` to the PDF `path` (A4, atomically), `footer` and "page N of M" at the
    foot of every page. PdfError (one line) when chromium is missing or fails."""
    chromium = chromium_path()
    with tempfile.TemporaryDirectory(prefix="trackcal-pdf-") as tmp:
        source = Path(tmp) / "page.html"
        source.write_text(page, encoding="utf-8")
        to_chromium, from_us = os.pipe()
        to_us, from_chromium = os.pipe()

        def fds():  # in the child: the protocol's descriptors 3 (commands in) and 4 (answers out), kept over exec
            a, b = os.dup(to_chromium), os.dup(from_chromium)  # either may already be 3 or 4
            os.dup2(a, 3)
            os.dup2(b, 4)
            os.set_inheritable(3, True)  # os.dup's copies are not, and dup2 onto itself changes nothing
            os.set_inheritable(4, True)

        proc = subprocess.Popen(
            [chromium, *FLAGS, f"--user-data-dir={Path(tmp) / 'profile'}", "about:blank"],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            close_fds=False,
            preexec_fn=fds,
        )
        os.close(to_chromium)
        os.close(from_chromium)
        try:
            pipe = _Pipe(proc, from_us, to_us, time.monotonic() + TIMEOUT_S)
            target = pipe.call("Target.createTarget", {"url": "about:blank"})["targetId"]
            session = pipe.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
            pipe.call("Page.enable", session=session)
            pipe.send("Page.navigate", {"url": source.as_uri()}, session)
            pipe.wait(event="Page.loadEventFired")
            pdf = pipe.call(
                "Page.printToPDF",
                {
                    "paperWidth": A4_IN[0],
                    "paperHeight": A4_IN[1],
                    "marginTop": MARGIN_IN,
                    "marginBottom": MARGIN_IN,
                    "marginLeft": MARGIN_IN,
                    "marginRight": MARGIN_IN,
                    "printBackground": True,
                    "displayHeaderFooter": True,
                    "headerTemplate": "<span></span>",
                    "footerTemplate": _footer(footer),
                },
                session,
            )
            with contextlib.suppress(OSError, subprocess.TimeoutExpired):  # printed: the close is a courtesy
                pipe.send("Browser.close")
                proc.wait(timeout=30)
        except OSError as exc:
            raise PdfError(f"chromium ended while printing the page: {exc}") from exc
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            os.close(from_us)
            os.close(to_us)
    write_bytes(path, base64.b64decode(pdf["data"]), PdfError)
    return path
