"""Which Robot Web Services trackcal speaks (drivers/abb/rws.py): 1.0, RobotWare 6. A RobotWare 7 controller (RWS
2.0: HTTPS only, HTTP Basic authentication) is told apart from a wrong password: its Basic challenge, or its redirect
of plain HTTP to HTTPS, ends the session in one line that says what it is. The controller here is a stub HTTP server
on loopback answering as such a controller answers a plain-HTTP, unauthenticated request (RFC 7617 section 2: a
Basic challenge is `WWW-Authenticate: Basic realm="..."`; RFC 9110 section 15.4.9: 308 with a Location)."""

from __future__ import annotations

import http.server
import threading

import pytest

from trackcal.drivers.abb.rws import RwsRefused, RwsSession
from trackcal.drivers.errors import ProtocolError


def _serve(status: int, headers: dict[str, str]):
    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 (http.server's name)
            self.send_response(status)
            for k, v in headers.items():
                self.send_header(k, v)
            self.send_header("Content-Length", "0")
            self.end_headers()

        def log_message(self, *args):
            """Quiet: http.server would print every request on stderr."""

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def _get_system(status: int, headers: dict[str, str]) -> Exception:
    server = _serve(status, headers)
    session = RwsSession(*server.server_address[:2], io_timeout_s=5.0)
    try:
        session.get("rw/system")
    except Exception as exc:  # noqa: BLE001 (what the session raised is the answer)
        return exc
    finally:
        session.close()
        server.shutdown()
    raise AssertionError("the stub controller's refusal was taken for an answer")


@pytest.mark.parametrize(
    "status, headers, seen",
    [
        (401, {"WWW-Authenticate": 'Basic realm="controller"'}, "HTTP 401 asking for 'Basic"),
        (308, {"Location": "https://127.0.0.1/rw/system"}, "HTTP 308 to https://"),
    ],
)
def test_a_robotware_7_controller_is_named_as_such_not_as_a_wrong_password(status, headers, seen):
    exc = _get_system(status, headers)
    assert isinstance(exc, ProtocolError) and not isinstance(exc, RwsRefused), exc
    assert "RobotWare 7 controller (Robot Web Services 2.0" in str(exc) and "RWS 1.0" in str(exc)
    assert seen in str(exc)
    # a RobotWare 6 controller's digest challenge that the password does not answer is still a refused password
    refused = _get_system(401, {"WWW-Authenticate": 'Digest realm="validusers@robapi.abb", nonce="abc", qop="auth"'})
    assert isinstance(refused, RwsRefused) and "user or password refused" in str(refused)
