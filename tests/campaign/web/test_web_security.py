"""The operator's page is closed (issue 22, README "The operator's page"): off loopback nothing without the token,
on loopback nothing for another Host (DNS rebinding), no answer from another origin or without the CSRF token,
a strict Content-Security-Policy on every response. At the HTTP level against the real server (uvicorn on a
thread), no browser needed."""

import http.client
import json
import re
import socket
import time

import pytest

from tests.helpers import feasible_plan
from trackcal.campaign.cli import main
from trackcal.campaign.engine.engine import Document
from trackcal.campaign.errors import InputError
from trackcal.campaign.jobs.campaign import new_session
from trackcal.campaign.web.app import MAX_BODY_BYTES, MAX_STREAMS
from trackcal.campaign.web.hub import PageOperator
from trackcal.campaign.web.server import WebPage, is_loopback


@pytest.fixture
def served(kr270, tmp_path, request):
    """A session (no campaign running) served by a page on the address of the test's parameter."""
    store, campaign = new_session(tmp_path / "s", "kr270", feasible_plan(kr270, 3, seed=11, repeat=1), "sim", 1)
    page = WebPage(request.param, 0, say=lambda text: None, out=lambda text: None)
    hub = page.attach(store, campaign.cell, campaign.steps)
    try:
        yield page, hub
    finally:
        page.close()
        store.close()


def fetch(page, method, path, headers=None, body=None):
    conn = http.client.HTTPConnection(page.host, page.port, timeout=10)
    try:
        conn.request(method, path, body=body, headers=headers or {})
        r = conn.getresponse()
        return r.status, dict((k.lower(), v) for k, v in r.getheaders()), r.read().decode(errors="replace")
    finally:
        conn.close()


def test_loopback_means_127_0_0_1_and_1_only():
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("127.0.0.2") and not is_loopback("0.0.0.0") and not is_loopback("192.168.1.10")


@pytest.mark.parametrize("served", ["127.0.0.2"], indirect=True)
def test_off_loopback_every_request_without_the_token_is_refused(served):
    page, _ = served
    assert page.token and f"?token={page.token}" in page.url
    for path in ("/", "/static/page.js", "/events?client=abcdefgh1234", "/report/report.html"):
        status, headers, _ = fetch(page, "GET", path)
        assert status == 403, path
        assert "default-src 'none'" in headers["content-security-policy"]
    status, _, _ = fetch(page, "GET", "/?token=wrong" + page.token[5:])
    assert status == 403
    # the token's URL opens the page and leaves an HttpOnly, SameSite=Strict cookie that carries it from then on
    status, headers, body = fetch(page, "GET", f"/?token={page.token}")
    assert status == 200 and '<script src="/static/page.js"' in body
    cookie = headers["set-cookie"]
    assert "HttpOnly" in cookie and "SameSite=Strict" in cookie
    status, _, _ = fetch(page, "GET", "/static/page.js", {"Cookie": cookie.split(";")[0]})
    assert status == 200


@pytest.mark.parametrize("served", ["127.0.0.1"], indirect=True)
def test_every_response_carries_a_strict_policy_and_no_inline_script(served):
    page, _ = served
    status, headers, body = fetch(page, "GET", "/")
    assert status == 200
    csp = headers["content-security-policy"]
    assert "default-src 'none'" in csp and "script-src 'self'" in csp and "unsafe-inline" not in csp
    assert "frame-ancestors 'none'" in csp and headers["x-content-type-options"] == "nosniff"
    assert not re.search(r"<script(?![^>]*\bsrc=)", body), "an inline script would be blocked by the policy"
    assert not re.search(r"\sstyle=|\son[a-z]+=", body), "inline styles and handlers are blocked too"
    assert not re.search(r"(src|href)=\"(https?:)?//", body), "nothing from outside the cell PC"


@pytest.mark.parametrize("served", ["127.0.0.1"], indirect=True)
def test_on_loopback_another_host_name_is_refused(served):
    """DNS rebinding: a site that points its own name at 127.0.0.1 sends its own Host."""
    page, _ = served
    status, _, _ = fetch(page, "GET", "/", {"Host": f"evil.example:{page.port}"})
    assert status == 403
    status, _, _ = fetch(page, "GET", "/", {"Host": f"localhost:{page.port}"})
    assert status == 200


@pytest.mark.parametrize("served", ["127.0.0.1"], indirect=True)
def test_an_answer_from_another_origin_or_without_the_csrf_token_is_refused(served):
    page, hub = served
    client = "abcdefgh12345678"
    hub.claim_control(client)
    prompt = {"kind": "resume", "target": "", "text": "resume"}
    hub.store.append("prompt", prompt)  # a prompt waiting, as the engine emits it: stored, then the hub hears it
    hub(Document("prompt", prompt))
    PageOperator(hub).offer("resume", "", "resume")
    assert hub.live["open"] == 1
    body = json.dumps({"client": client, "prompt": 1})
    own = f"http://127.0.0.1:{page.port}"
    good = {
        "Origin": own,
        "Content-Type": "application/json",
        "X-Trackcal-CSRF": hub.csrf,
        "Sec-Fetch-Site": "same-origin",
    }
    refused = [
        {**good, "Origin": "http://evil.example"},  # a cross-origin fetch
        {**good, "Sec-Fetch-Site": "cross-site"},
        {k: v for k, v in good.items() if k != "Origin"},
        {**good, "X-Trackcal-CSRF": "guess"},
        {**good, "Content-Type": "text/plain"},  # a "simple" cross-site form post
    ]
    for headers in refused:
        status, _, text = fetch(page, "POST", "/answer", headers, body)
        assert status == 403, (headers, text)
    with hub.lock:
        assert hub._answer is None
    # from another page that does not hold control: refused too
    status, _, text = fetch(page, "POST", "/answer", good, json.dumps({"client": "otherclient99", "prompt": 1}))
    assert status == 409 and "control" in text
    status, _, _ = fetch(page, "POST", "/answer", good, body)
    assert status == 200
    assert PageOperator(hub).poll() == "page abcdefgh from 127.0.0.1"


def test_a_port_in_use_is_one_line():
    first = WebPage("127.0.0.1", 0, say=lambda text: None)
    try:
        with pytest.raises(InputError, match=f"--web-port {first.port}: cannot listen there"):
            WebPage("127.0.0.1", first.port, say=lambda text: None)
    finally:
        first.close()


def test_the_page_options_belong_to_operator_web(tmp_path, capsys):
    plan = tmp_path / "plan.json"
    plan.write_text("{}")
    code = main(
        [
            "run",
            "--cell",
            "kr270",
            "--plan",
            str(plan),
            "--sim",
            "--session",
            str(tmp_path / "s"),
            "--web-host",
            "0.0.0.0",
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and err.strip() == "error: --web-host, --web-port and --web-linger are for --operator web"
    assert not (tmp_path / "s").exists()


def raw_request(page, head: str, body: bytes = b"", timeout_s: float = 10.0):
    """A request over a raw socket; the open socket and the response's status line and headers (the body is left
    unread: an event stream goes on)."""
    s = socket.create_connection((page.host, page.port), timeout=timeout_s)
    s.sendall(head.encode("latin-1") + body)
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = s.recv(4096)
        if not chunk:
            break
        data += chunk
    return s, data.split(b"\r\n\r\n", 1)[0].decode("latin-1")


def stream_head(page, csrf: str, client: str = "abcdefgh1234") -> str:
    return (
        f"GET /events?client={client}&csrf={csrf} HTTP/1.1\r\nHost: 127.0.0.1:{page.port}\r\n"
        "Sec-Fetch-Site: same-origin\r\n\r\n"
    )


@pytest.mark.parametrize("served", ["127.0.0.1"], indirect=True)
def test_the_event_stream_needs_the_page_token(served):
    """A page of another origin opens the stream first (an EventSource needs no CORS to be sent): refused, and
    control stays free for the cell's page, which reads the token from /session (another origin cannot)."""
    page, hub = served
    own = f"http://127.0.0.1:{page.port}"

    def stream_status(query: str, headers: dict) -> str:  # the status line alone: a stream that opened goes on
        extra = "".join(f"{k}: {v}\r\n" for k, v in headers.items())
        s, head = raw_request(page, f"GET /events?{query} HTTP/1.1\r\nHost: 127.0.0.1:{page.port}\r\n{extra}\r\n")
        s.close()
        return head.split("\r\n")[0]

    for headers in ({}, {"Origin": "http://evil.example", "Sec-Fetch-Site": "cross-site"}):
        assert " 403 " in stream_status("client=evilpage1234", headers), headers
    for headers in ({"Origin": "http://evil.example"}, {"Sec-Fetch-Site": "same-site"}):
        status, _, _ = fetch(page, "GET", "/session", headers)
        assert status == 403, headers
        assert " 403 " in stream_status(f"client=evilpage1234&csrf={hub.csrf}", headers), headers
    assert " 403 " in stream_status("client=evilpage1234&csrf=guess", {})
    assert hub.live["controller"] is None
    status, _, body = fetch(page, "GET", "/session", {"Sec-Fetch-Site": "same-origin"})
    assert status == 200 and json.loads(body)["csrf"] == hub.csrf
    status, _, _ = fetch(page, "GET", "/session", {"Origin": own})  # a same-origin fetch may send its Origin
    assert status == 200
    assert " 200 " in stream_status(f"client=cellpage1234&csrf={hub.csrf}", {"Sec-Fetch-Site": "same-origin"})
    assert hub.live["controller"] == "cellpage1234"


@pytest.mark.parametrize("served", ["127.0.0.1"], indirect=True)
def test_a_large_body_is_refused_unread(served):
    """A 300 MB answer (issue 42: it took the process to 638 MB): 413 on its stated length alone, before one byte of
    it is sent; a chunked body is read up to the cap only."""
    page, hub = served
    head = (
        f"POST /answer HTTP/1.1\r\nHost: 127.0.0.1:{page.port}\r\nOrigin: http://127.0.0.1:{page.port}\r\n"
        f"Content-Type: application/json\r\nX-Trackcal-CSRF: {hub.csrf}\r\n"
    )
    s, status = raw_request(page, head + f"Content-Length: {300 * 2**20}\r\n\r\n", timeout_s=5.0)
    with s:
        assert status.startswith("HTTP/1.1 413"), status
    chunk = b"%x\r\n%s\r\n" % (4096, b" " * 4096)
    s, status = raw_request(
        page, head + "Transfer-Encoding: chunked\r\n\r\n", chunk * (MAX_BODY_BYTES // 4096 + 1), timeout_s=5.0
    )
    with s:
        assert status.startswith("HTTP/1.1 413"), status
    assert MAX_BODY_BYTES <= 64 * 1024  # a small stated size: an answer is ~60 bytes of JSON


def test_event_streams_are_capped(kr270, tmp_path):
    """300 streams were accepted (issue 42): beyond MAX_STREAMS a page gets 503, the console one line however many
    are refused; a stream that closes makes room again."""
    store, campaign = new_session(tmp_path / "s", "kr270", feasible_plan(kr270, 3, seed=11, repeat=1), "sim", 1)
    said = []
    page = WebPage("127.0.0.1", 0, say=said.append, out=lambda text: None)
    hub = page.attach(store, campaign.cell, campaign.steps)
    said.clear()
    opened = []
    try:
        for k in range(MAX_STREAMS):
            s, head = raw_request(page, stream_head(page, hub.csrf, f"client{k:04d}"))
            opened.append(s)
            assert head.startswith("HTTP/1.1 200"), (k, head)
        for k in range(3):
            s, head = raw_request(page, stream_head(page, hub.csrf, f"refused{k:04d}"))
            s.close()
            assert head.startswith("HTTP/1.1 503"), head
        assert len(said) == 1 and f"{MAX_STREAMS} event streams open" in str(said[0])
        opened.pop().close()
        deadline = time.monotonic() + 10  # the server sees the closed stream at its next heartbeat
        while True:
            s, head = raw_request(page, stream_head(page, hub.csrf, "again0001"))
            s.close()
            if head.startswith("HTTP/1.1 200") or time.monotonic() > deadline:
                break
            time.sleep(0.2)
        assert head.startswith("HTTP/1.1 200"), head
    finally:
        for s in opened:
            s.close()
        page.close()
        store.close()
