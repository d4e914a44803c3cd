"""Robot Web Services 1.0 (RobotWare 6) over HTTP: digest authentication, the session cookies, JSON answers.

Which RWS: 1.0 only, the REST interface of RobotWare 6 (ABB, "Application Manual - Robot Web Services",
3HAC050973-001, developercenter.robotstudio.com/api/rwsApi/). RWS 2.0 (RobotWare 7, OmniCore controllers: ABB's
"Robot Web Services 2.0" reference, developercenter.robotstudio.com/api/RWS) is another protocol: HTTPS only, HTTP
Basic authentication instead of digest, versioned media types (`Accept: application/hal+json;v=2.0`, form posts as
`application/x-www-form-urlencoded;v=2.0`) and changed resources and answers ("For the RW 7.0 release, RWS has
introduced several breaking changes", the RobotWare 7 client rwswrap, pypi.org/project/rwswrap). trackcal speaks 1.0
because its ABB arms (the IRB 120s of its real data sets, the IRB 6700 twin) are IRC5 controllers with RobotWare 6,
and because its judge, abb-robot-client, speaks 1.0 only: a 2.0 dialect would have no independent client to be judged
by. A RobotWare 7 controller is recognised, not misread: its Basic challenge (401 with `WWW-Authenticate: Basic`) or
its redirect of plain HTTP to HTTPS ends the session in one ProtocolError saying so (`RWS2_REFUSED`), where it would
otherwise read as a wrong password.

What this module relies on (the manual's pages named; each is `curl --digest -u "Default User":robotics URL`):
- every request is HTTP digest authenticated (RFC 7616, MD5, qop=auth) until the controller hands out its session
  cookies `-http-session-` and `ABBCX` (the manual's "Authentication and sessions": a session cookie saves the
  digest on later requests; the websocket subscriptions need ABBCX); a 401 with a fresh challenge (the session
  expired, the nonce went stale) is answered once with a new digest;
- `?json=1` asks for JSON instead of XHTML (the manual's "Common URL parameters"): the answer's
  `_embedded._state` is the list of the XHTML page's `<li>` items, each with `_type` (the li's class), `_title` and
  the spans as keys; an error answer's `_embedded.status` carries the controller's return `code` and `msg`;
- 503 Service Unavailable: too many sessions, or the controller busy (the manual's "HTTP Status codes");
- writes are POSTs with form-encoded data (`value=...`, `stopmode=stop`, ...), answered 204 No Content.

Every failure is one DeviceError line naming the controller: ConnectionLost (unreachable, dropped), DeviceTimeout
(no answer within io_timeout_s), ProtocolError (an answer that is not RWS JSON), DeviceFault (the controller's
refusal: its HTTP status and return code).
"""

from __future__ import annotations

import contextlib
import hashlib
import http.client
import json
import os
import re
import socket
import threading
import urllib.parse

from trackcal.drivers.errors import ConnectionLost, DeviceFault, DeviceTimeout, ProtocolError

DEFAULT_USER = "Default User"  # the user every RobotWare 6 system has (the manual's sample calls)
DEFAULT_PASSWORD = "robotics"
SESSION_COOKIES = ("-http-session-", "ABBCX")
RWS2_REFUSED = (
    "answers as a RobotWare 7 controller (Robot Web Services 2.0: HTTPS, Basic authentication), which "
    "trackcal does not speak: it drives RobotWare 6 controllers over RWS 1.0 (docs/abb.md)"
)
_REDIRECTS = (301, 302, 303, 307, 308)
_PARAM = re.compile(r'(\w+)=(?:"((?:[^"\\]|\\.)*)"|([^,\s]*))')


class RwsRefused(DeviceFault):
    """The controller answered with an HTTP error: `status` the HTTP status, `code` its return code (or the
    status when the answer carries none)."""

    def __init__(self, message: str, *, status: int, code: int | str | None, device: str = "") -> None:
        self.status = status
        super().__init__(message, code=code, device=device)


def parse_challenge(header: str) -> dict[str, str]:
    """The parameters of a `WWW-Authenticate: Digest ...` header (RFC 7616 section 3.3); {} for another scheme."""
    scheme, _, rest = header.strip().partition(" ")
    if scheme.lower() != "digest":
        return {}
    return {k.lower(): (q.replace('\\"', '"') if q else b) for k, q, b in _PARAM.findall(rest)}


def digest_response(
    user: str, password: str, method: str, uri: str, challenge: dict[str, str], nc: int, cnonce: str
) -> str:
    """The `Authorization: Digest ...` header's value for one request (RFC 7616 section 3.4, MD5, qop=auth or none)."""

    def h(text: str) -> str:
        return hashlib.md5(text.encode("utf-8")).hexdigest()  # the digest RFC 7616 names MD5; not for secrecy here

    realm, nonce = challenge.get("realm", ""), challenge.get("nonce", "")
    ha1, ha2 = h(f"{user}:{realm}:{password}"), h(f"{method}:{uri}")
    qops = [q.strip() for q in challenge.get("qop", "").split(",") if q.strip()]
    fields = {"username": user, "realm": realm, "nonce": nonce, "uri": uri}
    if "auth" in qops:
        count = f"{nc:08x}"
        fields["response"] = h(f"{ha1}:{nonce}:{count}:{cnonce}:auth:{ha2}")
        text = ", ".join(f'{k}="{v}"' for k, v in fields.items())
        text += f', qop=auth, nc={count}, cnonce="{cnonce}"'
    else:
        fields["response"] = h(f"{ha1}:{nonce}:{ha2}")
        text = ", ".join(f'{k}="{v}"' for k, v in fields.items())
    if "opaque" in challenge:
        text += f', opaque="{challenge["opaque"]}"'
    return f"Digest {text}, algorithm=MD5"


def states(doc: dict) -> list[dict]:
    """The `_embedded._state` items of an RWS JSON answer."""
    try:
        items = doc["_embedded"]["_state"]
    except (KeyError, TypeError):
        raise ValueError("no _embedded._state in the answer") from None
    if not isinstance(items, list) or not all(isinstance(i, dict) for i in items):
        raise ValueError("_embedded._state is not a list of items")
    return items


class RwsSession:
    """One RWS 1.0 session with a controller at `host:port` (HTTP; one connection, kept alive, one request at a
    time: a lock serialises the moving thread and a stop from another)."""

    def __init__(
        self,
        host: str,
        port: int = 80,
        *,
        user: str = DEFAULT_USER,
        password: str = DEFAULT_PASSWORD,
        io_timeout_s: float = 5.0,
    ) -> None:
        self.host, self.port = host, int(port)
        self.user, self.password = user, password
        self.io_timeout_s = io_timeout_s
        self.device = f"ABB RWS {host}:{port}"
        self.cookies: dict[str, str] = {}
        self._challenge: dict[str, str] | None = None
        self._nc = 0
        self._conn: http.client.HTTPConnection | None = None
        self._lock = threading.Lock()

    def get(self, path: str, **params: str) -> list[dict]:
        """The `_state` items of GET path (JSON)."""
        return states(self._json(self.request("GET", path, params)))

    def post(self, path: str, params: dict[str, str] | None = None, data: dict[str, str] | None = None) -> dict | None:
        """POST form data to path; the answer's JSON (None for 204 No Content)."""
        body = self.request("POST", path, params or {}, data or {})
        return self._json(body) if body else None

    def request(self, method: str, path: str, params: dict[str, str], data: dict[str, str] | None = None) -> bytes:
        """The body of a 2xx answer (RwsRefused for another status), digest-authenticated when challenged."""
        uri = "/" + path.lstrip("/") + "?" + urllib.parse.urlencode({**params, "json": "1"})
        body = urllib.parse.urlencode(data).encode("ascii") if data is not None else None
        with self._lock:
            status, headers, payload = self._exchange(method, uri, body)
            if status == 401:  # no session yet, or it expired: answer the challenge once
                self.cookies.clear()
                self._challenge = parse_challenge(headers.get("www-authenticate", ""))
                self._nc = 0
                if not self._challenge:
                    self._rws2(method, path, headers, f"HTTP 401 asking for {headers.get('www-authenticate')!r}")
                status, headers, payload = self._exchange(method, uri, body)
        if status in _REDIRECTS and headers.get("location", "").lower().startswith("https:"):
            self._rws2(method, path, headers, f"HTTP {status} to {headers['location']}")
        if 200 <= status < 300:
            return payload
        raise self._refusal(method, path, status, payload)

    def _rws2(self, method: str, path: str, headers: dict[str, str], seen: str) -> None:
        """A Basic challenge or a redirect to HTTPS: RobotWare 7, not RWS 1.0 (the module docstring)."""
        if "digest" in headers.get("www-authenticate", "").lower():
            return  # a digest challenge beside it: RWS 1.0 after all
        raise ProtocolError(f"{method} {path}: the controller {RWS2_REFUSED} ({seen})", device=self.device)

    def close(self) -> None:
        with self._lock:
            self._drop()
            self.cookies.clear()

    # --- wire ----------------------------------------------------------------------------------------------------

    def _exchange(self, method: str, uri: str, body: bytes | None) -> tuple[int, dict[str, str], bytes]:
        headers = {"Accept": "application/json", "Connection": "keep-alive"}
        if body is not None:
            headers["Content-Type"] = "application/x-www-form-urlencoded"
        if self.cookies:
            headers["Cookie"] = "; ".join(f"{k}={v}" for k, v in self.cookies.items())
        elif self._challenge:
            self._nc += 1
            headers["Authorization"] = digest_response(
                self.user, self.password, method, uri, self._challenge, self._nc, os.urandom(8).hex()
            )
        for attempt in (1, 2):  # a kept-alive connection the controller closed meanwhile is opened again once
            conn = self._connection()
            try:
                conn.request(method, uri, body=body, headers=headers)
                response = conn.getresponse()
                payload = response.read()
            except TimeoutError as exc:
                self._drop()
                raise DeviceTimeout(
                    f"{method} {uri}: no answer within {self.io_timeout_s} s", device=self.device
                ) from exc
            except (OSError, http.client.HTTPException) as exc:
                self._drop()
                if attempt == 2 or isinstance(exc, ConnectionRefusedError | socket.gaierror):
                    raise ConnectionLost(f"{method} {uri}: {exc or type(exc).__name__}", device=self.device) from exc
                continue
            answer = {k.lower(): v for k, v in response.getheaders()}
            self._keep_cookies(response.headers.get_all("Set-Cookie") or [])
            if answer.get("connection", "").lower() == "close":
                self._drop()
            return response.status, answer, payload
        raise AssertionError("unreachable")

    def _connection(self) -> http.client.HTTPConnection:
        if self._conn is None:
            self._conn = http.client.HTTPConnection(self.host, self.port, timeout=self.io_timeout_s)
        return self._conn

    def _drop(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def _keep_cookies(self, lines: list[str]) -> None:
        for line in lines:
            name, _, value = line.split(";", 1)[0].strip().partition("=")
            if name in SESSION_COOKIES:
                self.cookies[name] = value

    def _json(self, payload: bytes) -> dict:
        try:
            doc = json.loads(payload)
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ProtocolError(f"not RWS JSON: {payload[:80]!r}", device=self.device) from exc
        if not isinstance(doc, dict):
            raise ProtocolError(f"not RWS JSON: {payload[:80]!r}", device=self.device)
        return doc

    def _refusal(self, method: str, path: str, status: int, payload: bytes) -> RwsRefused:
        code: int | str | None = status
        msg = http.client.responses.get(status, "HTTP error")
        with contextlib.suppress(ValueError, KeyError, TypeError):  # no RWS error document: the HTTP status stands
            err = json.loads(payload)["_embedded"]["status"]
            code, msg = int(err["code"]), str(err.get("msg") or msg)
        why = {401: " (user or password refused)", 503: " (controller busy, or too many RWS sessions)"}.get(status, "")
        return RwsRefused(f"{method} {path}: HTTP {status} {msg}{why}", status=status, code=code, device=self.device)
