"""The page's web application (Starlette): the page itself, its script and style (files: the strict
Content-Security-Policy allows no inline script), the server-sent event stream of the campaign, the answers,
and the report once written.

Closed by default (README, "The operator's page"):
- `Guard` refuses with 403 every request without the access token when the server listens on another address
  than loopback (the token comes in the URL the console prints, and is then kept in an HttpOnly, SameSite=Strict
  cookie); on loopback, a request whose Host is not the loopback address is refused too (DNS rebinding: a web
  site that points its own name at 127.0.0.1 cannot read or answer the page).
- Every response carries a strict Content-Security-Policy (nothing but this server: no inline script, no
  framing), nosniff, no referrer, no caching.
- An answer is a POST of JSON with the per-process CSRF token in a header (a cross-site form cannot set a
  header or send JSON without a preflight, which this server never grants), and it is refused when the browser
  says it comes from another site: `Origin` must be this server's (RFC 6454; browsers send it on every POST) and
  `Sec-Fetch-Site`, when sent, `same-origin` (W3C Fetch Metadata Request Headers).
- The event stream needs the page's token like a POST (the page reads it from /session, which only a page of this
  server's own origin can read), and is refused, as a POST is, when the browser says it comes from another origin:
  a page elsewhere cannot open it first and take control.
- A request body is at most MAX_BODY_BYTES (413 without reading more); at most MAX_STREAMS event streams are open
  at once (503 beyond, one line on the console when the cap is reached).
- One page holds control (the first to connect, or the last to press "take control"); the others watch.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import re
from collections.abc import AsyncIterator
from importlib import resources
from pathlib import Path
from urllib.parse import parse_qs

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response, StreamingResponse
from starlette.routing import Route

from trackcal.campaign.engine.steps import Step
from trackcal.campaign.web.hub import Hub
from trackcal.campaign.web.state import PageState

CSP = (
    "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self'; connect-src 'self'; "
    "base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
)
# the report is trackcal's own HTML with its inline style and embedded figures: shown sandboxed (no script at all)
REPORT_CSP = "default-src 'none'; style-src 'unsafe-inline'; img-src 'self' data:; sandbox; frame-ancestors 'none'"
HEADERS = {
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-store",
    "X-Frame-Options": "DENY",
    "Cross-Origin-Opener-Policy": "same-origin",
    "Cross-Origin-Resource-Policy": "same-origin",
}
COOKIE = "trackcal_token"
CLIENT_ID = re.compile(r"^[A-Za-z0-9_-]{8,64}$")
STATIC = {"page.js": "text/javascript; charset=utf-8", "page.css": "text/css; charset=utf-8"}
HEARTBEAT_S = 1.0  # the page says the campaign stopped when it hears nothing for a few of these (page.js)
# An answer is ~60 bytes of JSON: 16 KiB is room for anything the page sends and bounds what a request can cost.
MAX_BODY_BYTES = 16 * 1024
# The cell's tablet, a few phones watching, the tabs of a reload: 16 open streams. Each costs a queue of the
# campaign's documents and a task; a page beyond the cap is refused with 503 and retries (page.js RECONNECT_MS).
MAX_STREAMS = 16


def static_text(name: str) -> bytes:
    return resources.files("trackcal.campaign.web").joinpath("static", name).read_bytes()


def _refuse(why: str = "forbidden") -> Response:
    return Response(why + "\n", status_code=403, media_type="text/plain")


class Guard:
    """ASGI middleware: the token (off loopback), the Host (on loopback), the body's size, and the security
    headers."""

    def __init__(self, app, token: str | None, loopback_hosts: set[str] | None) -> None:
        self.app, self.token, self.hosts = app, token, loopback_hosts

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        set_cookie, refused = False, None
        if self.hosts is not None and headers.get("host", "") not in self.hosts:
            refused = _refuse("forbidden: unknown Host")
        elif self.token is not None:
            given = query.get("token", [""])[0]
            cookie = _cookie(headers.get("cookie", ""), COOKIE)
            if given and hmac.compare_digest(given, self.token):
                set_cookie = True
            elif not (cookie and hmac.compare_digest(cookie, self.token)):
                refused = _refuse("forbidden: open the URL with the token that trackcal printed")
        report = refused is None and scope.get("path", "").startswith("/report/")

        async def send_with_headers(message):
            if message["type"] == "http.response.start":
                extra = [(k.lower().encode(), v.encode()) for k, v in HEADERS.items()]
                extra.append((b"content-security-policy", (REPORT_CSP if report else CSP).encode()))
                if set_cookie:
                    extra.append((b"set-cookie", f"{COOKIE}={self.token}; HttpOnly; SameSite=Strict; Path=/".encode()))
                message = {**message, "headers": [*message.get("headers", []), *extra]}
            await send(message)

        if refused is None:
            receive, refused = await _capped(headers, receive)
        if refused is not None:
            return await refused(scope, receive, send_with_headers)
        return await self.app(scope, receive, send_with_headers)


async def _capped(headers: dict[str, str], receive):
    """(receive, None) for a body of at most MAX_BODY_BYTES, else (receive, a 413 response). A stated length is
    judged before a byte is read; a chunked body is read up to the cap and handed on from memory."""
    too_large = Response(f"request body over {MAX_BODY_BYTES} bytes\n", status_code=413, media_type="text/plain")
    length = headers.get("content-length")
    if length is not None:
        ok = length.isdigit() and int(length) <= MAX_BODY_BYTES
        return receive, None if ok else too_large
    if "chunked" not in headers.get("transfer-encoding", "").lower():
        return receive, None
    body, more = b"", True
    while more:
        message = await receive()
        if message["type"] != "http.request":
            return receive, None  # the client went away: the app sees it
        body += message.get("body", b"")
        more = message.get("more_body", False)
        if len(body) > MAX_BODY_BYTES:
            return receive, too_large
    sent = False

    async def replay():
        nonlocal sent
        if not sent:
            sent = True
            return {"type": "http.request", "body": body, "more_body": False}
        return await receive()

    return replay, None


class _Released:
    """A response (ASGI) that calls `release` once it has ended, however it ended."""

    def __init__(self, response: Response, release) -> None:
        self.response, self.release = response, release

    async def __call__(self, scope, receive, send) -> None:
        try:
            await self.response(scope, receive, send)
        finally:
            self.release()


def _cookie(header: str, name: str) -> str:
    for part in header.split(";"):
        k, _, v = part.strip().partition("=")
        if k == name:
            return v
    return ""


def build_app(
    hub: Hub,
    steps: list[Step],
    token: str | None,
    loopback_hosts: set[str] | None,
    report_dir: Path | None = None,
    closing=None,
    say=lambda line: None,
) -> Guard:
    """The application around a hub; `report_dir`: the session's report folder (served once the outcome is set);
    `closing`: an event (threading.Event) set when the server is about to stop, which ends the event streams;
    `say`: a line on the console (the stream cap reached)."""
    streams = {"open": 0, "said": False}  # touched in the server's event loop only

    async def index(request: Request) -> Response:
        return Response(static_text("index.html"), media_type="text/html; charset=utf-8")

    async def static(request: Request) -> Response:
        name = request.path_params["name"]
        if name not in STATIC:
            return Response("not found\n", status_code=404, media_type="text/plain")
        return Response(static_text(name), media_type=STATIC[name])

    async def session(request: Request) -> Response:
        why = _other_origin(request)
        return _refuse(why) if why else JSONResponse({"csrf": hub.csrf})

    async def events(request: Request) -> Response:
        return _open_stream(request, hub, steps, streams, closing, say)

    async def answer(request: Request) -> Response:
        return await _post(request, hub, _do_answer)

    async def control(request: Request) -> Response:
        return await _post(request, hub, _do_control)

    async def report(request: Request) -> Response:
        return _report_file(request, hub, report_dir)

    routes = [
        Route("/", index),
        Route("/static/{name}", static),
        Route("/session", session),
        Route("/events", events),
        Route("/answer", answer, methods=["POST"]),
        Route("/control", control, methods=["POST"]),
        Route("/report/{path:path}", report),
        Route("/favicon.ico", lambda request: Response(status_code=204)),
    ]
    return Guard(Starlette(routes=routes), token, loopback_hosts)


def _open_stream(request: Request, hub: Hub, steps: list[Step], streams: dict, closing, say) -> Response:
    """/events: one page's event stream, once the request passes the origin and page-token checks and the client id
    is well formed; refused (503) while MAX_STREAMS are open, said once on the console (`say`) until one closes.
    `streams` counts the open ones (touched in the server's event loop only)."""
    why = _other_origin(request)
    if not why and not hmac.compare_digest(request.query_params.get("csrf", ""), hub.csrf):
        why = "forbidden: no valid page token (the page reads it from /session)"
    if why:
        return _refuse(why)
    client = request.query_params.get("client", "")
    if not CLIENT_ID.match(client):
        return Response("client: 8 to 64 letters, digits, - or _\n", status_code=400, media_type="text/plain")
    if streams["open"] >= MAX_STREAMS:
        if not streams["said"]:
            streams["said"] = True
            say(
                f"warning: the operator's page has {MAX_STREAMS} event streams open, the most it serves: "
                "another page is refused until one closes"
            )
        return Response("too many pages open\n", status_code=503, media_type="text/plain", headers={"Retry-After": "2"})
    queue: asyncio.Queue = asyncio.Queue()
    loop = asyncio.get_running_loop()

    def push(kind, item):  # from the engine's thread: never blocks
        with contextlib.suppress(RuntimeError):  # the loop has ended
            loop.call_soon_threadsafe(queue.put_nowait, (kind, item))

    past, live = hub.subscribe(push)
    hub.claim_control(client)
    state = PageState(steps, hub.plan).fold(past)

    def release() -> None:  # however the response ends, even before the stream started
        hub.unsubscribe(push)
        streams["open"] -= 1
        if streams["open"] < MAX_STREAMS:
            streams["said"] = False

    streams["open"] += 1  # no await since the count was read: no other request came in between
    return _Released(
        StreamingResponse(
            _event_stream(hub, state, past, live, queue, closing, push),
            media_type="text/event-stream",
            headers={"X-Accel-Buffering": "no"},
        ),
        release,
    )


async def _event_stream(
    hub: Hub, state: PageState, past: list, live: dict, queue: asyncio.Queue, closing, push
) -> AsyncIterator[str]:
    """One page's server-sent events: the snapshot of what happened so far, then a patch per burst of documents,
    the live values, a ping every HEARTBEAT_S; ends on the hub's close or once `closing` is set."""
    try:
        yield f"retry: {int(HEARTBEAT_S * 1000)}\n\n"
        yield _sse(
            "snapshot",
            {
                "view": state.view,
                "points": state.points,
                "plan": hub.plan,
                "live": {**live, "controller": hub.live["controller"]},
                "events": len(past),
            },
        )
        while True:
            try:
                kind, item = await asyncio.wait_for(queue.get(), timeout=HEARTBEAT_S)
            except TimeoutError:
                if closing is not None and closing.is_set():
                    return
                yield _sse("ping", {})
                continue
            # everything already waiting goes in one message (a campaign emits bursts of documents)
            batch = [(kind, item)]
            while not queue.empty():
                batch.append(queue.get_nowait())
            changed, added, live_now, last = set(), [], {}, None
            for kind, item in batch:
                if kind == "close":
                    return
                if kind == "live":
                    live_now.update(item)
                    continue
                c, a = state.apply(item)
                changed |= c
                added += a
                last = item.id
            if live_now:
                yield _sse("live", live_now)
            if changed or added:
                yield _sse("patch", {"id": last, "set": {k: state.view[k] for k in changed}, "add": added})
    finally:
        hub.unsubscribe(push)


async def _post(request: Request, hub: Hub, action) -> Response:
    """A POST of the page (an answer, taking control): refused unless same-site with the page token and a client id."""
    why = _cross_site(request, hub.csrf)
    if why:
        return _refuse(why)
    try:
        body = json.loads(await request.body())
    except ValueError:
        return JSONResponse({"ok": False, "why": "not JSON"}, status_code=400)
    client = body.get("client") if isinstance(body, dict) else None
    if not isinstance(client, str) or not CLIENT_ID.match(client):
        return JSONResponse({"ok": False, "why": "no client"}, status_code=400)
    return action(request, hub, body, client)


def _do_answer(request: Request, hub: Hub, body: dict, client: str) -> Response:
    prompt = body.get("prompt")
    if not isinstance(prompt, int) or isinstance(prompt, bool):
        return JSONResponse({"ok": False, "why": "no prompt"}, status_code=400)
    source = f"page {client[:8]} from {request.client.host if request.client else '?'}"
    why = hub.answer(prompt, client, source)
    if why:
        return JSONResponse({"ok": False, "why": why}, status_code=409)
    return JSONResponse({"ok": True})


def _do_control(request: Request, hub: Hub, body: dict, client: str) -> Response:
    hub.take_control(client)
    return JSONResponse({"ok": True})


def _report_file(request: Request, hub: Hub, report_dir: Path | None) -> Response:
    """A file of the session's report folder, once the campaign's outcome is set; nothing outside the folder."""
    if report_dir is None or hub.live.get("outcome") is None:
        return Response("no report yet\n", status_code=404, media_type="text/plain")
    base = report_dir.resolve()
    path = (base / request.path_params["path"]).resolve()
    if not path.is_relative_to(base) or not path.is_file():
        return Response("not found\n", status_code=404, media_type="text/plain")
    return FileResponse(path)


def _other_origin(request: Request) -> str:
    """Why a GET of the page's own (its token, its stream) is refused as coming from another origin ("" when it is
    not): a browser sends `Origin` on every cross-origin fetch or EventSource (and may omit it on a same-origin GET),
    and `Sec-Fetch-Site` names the requester's relation to this server."""
    origin = request.headers.get("origin")
    if origin is not None and origin != f"{request.url.scheme}://{request.headers.get('host', '')}":
        return "forbidden: cross-origin request"
    if request.headers.get("sec-fetch-site", "same-origin") != "same-origin":
        return "forbidden: cross-site request"
    return ""


def _cross_site(request: Request, csrf: str) -> str:
    """Why a POST is refused as coming from another site ("" when it is not): as `_other_origin`, and `Origin` must
    be sent."""
    if request.headers.get("origin") is None:
        return "forbidden: cross-origin request"
    why = _other_origin(request)
    if why:
        return why
    if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
        return "forbidden: not JSON"
    if not hmac.compare_digest(request.headers.get("x-trackcal-csrf", ""), csrf):
        return "forbidden: no valid CSRF token"
    return ""


def _sse(event: str, data: object) -> str:
    """One server-sent event (WHATWG HTML, 9.2 Server-sent events: `event:` and `data:` lines, a blank line)."""
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'), allow_nan=False)}\n\n"
