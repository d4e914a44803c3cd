"""The mock IRC5 (mocks/servers/abb): its motion and RAPID rules tick by tick (no sockets), then its Robot Web
Services answers over HTTP in this process: what a RobotWare 6 controller answers to a client without a session
(401 and a digest challenge), to an unknown resource (404), when busy (503), and its session cookies."""

from __future__ import annotations

import http.client
import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackcal.calib.model.cell import load_robot
from trackcal.drivers.abb.program import DONE, MOVE, SPEED, TARGET, joint_value
from trackcal.drivers.abb.rws import RwsRefused, RwsSession, parse_challenge
from trackcal.mocks.servers.abb.controller import ACCEL_S, TICK_S, AbbController, RapidError
from trackcal.mocks.servers.abb.rws_server import REALM, flange_of
from trackcal.mocks.servers.abb.server import AbbServer

HOME = (0.0, 0.0, 0.0, 0.0, 30.0, 0.0)


def running(q0=HOME) -> AbbController:
    c = AbbController(q0)
    c.set_ctrlstate("motoron")
    c.start()
    return c


def request_move(c: AbbController, target, pct: float, number: int) -> None:
    c.write(TARGET, joint_value(target))
    c.write(SPEED, str(pct))
    c.write(MOVE, str(number))


def test_a_move_takes_the_datasheet_axis_speed_and_answers_done():
    # IRB 120 product specification: axis 1 at most 250 deg/s. 100 deg at 100 %: 0.4 s at full speed, plus one
    # ACCEL_S (reaching and leaving the speed on a trapezoid cost half of ACCEL_S each), 0.5 s = 125 ticks of 4 ms
    c = running()
    request_move(c, (100, 0, 0, 0, 30, 0), 100, 1)
    ticks = 0
    while c.read(DONE) != "1":
        c.tick()
        ticks += 1
        assert ticks < 1000
    expected = (100 / 250 + ACCEL_S) / TICK_S
    assert abs(ticks - expected) <= 2  # the first tick starts the move, the last one answers it
    assert c.q == pytest.approx((100, 0, 0, 0, 30, 0), abs=0)


def test_a_rapid_stop_brakes_on_the_path_and_resetpp_drops_the_move():
    c = running()
    request_move(c, (100, 0, 0, 0, 30, 0), 100, 1)
    for _ in range(60):
        c.tick()
    at_stop = c.q[0]
    c.stop()
    for _ in range(int(ACCEL_S / TICK_S) + 2):
        c.tick()
    braked = c.q[0]
    for _ in range(50):
        c.tick()
    assert c.q[0] == braked  # standing
    # at most full speed over ACCEL_S, half of it on a linear ramp: 250 deg/s * 0.1 s / 2 = 12.5 deg
    assert at_stop < braked <= at_stop + 12.5 + 1e-9
    assert c.read(DONE) == "0" and c.snapshot()["execution"] == "stopped"
    c.resetpp()
    c.write(DONE, c.read(MOVE))  # what the client does before it starts RAPID again
    c.start()
    for _ in range(100):
        c.tick()
    assert c.q[0] == braked  # the stopped move is not resumed


def test_a_guard_stop_halts_at_once_and_refuses_motors_on_until_released():
    c = running()
    request_move(c, (50, 0, 0, 0, 30, 0), 100, 1)
    for _ in range(40):
        c.tick()
    c.fault("guardstop")
    q = c.q
    c.tick()
    assert c.q == q and c.snapshot()["ctrlstate"] == "guardstop"
    with pytest.raises(RapidError):
        c.set_ctrlstate("motoron")
    c.fault("release")
    c.set_ctrlstate("motoron")
    codes = [e[2] for e in c.elog]
    # RobotWare's event numbers: 10010 motors off, 10011 motors on, 10012 safety guard stop
    assert codes == [10010, 10011, 10012, 10010, 10011]


def test_rapid_values_are_32_bit_floats_and_bad_values_are_refused():
    c = AbbController(HOME)
    c.write(SPEED, "0.1")
    assert c.read(SPEED) == "0.100000001"  # 0.1 as an IEEE 754 single, to 9 significant digits
    with pytest.raises(RapidError):
        c.write(TARGET, "[[1,2,3],[9E9]]")
    with pytest.raises(KeyError):
        c.read("nothing")


@pytest.fixture
def served():
    chain, _ = load_robot("irb120")
    c = running()
    server = AbbServer(c, flange_of(chain), seed=7).start()
    yield server
    server.stop()


def raw(server: AbbServer, method: str, path: str, headers=None, body=None):
    conn = http.client.HTTPConnection(*server.address, timeout=5)
    conn.request(method, path, body=body, headers=headers or {})
    r = conn.getresponse()
    out = r.status, {k.lower(): v for k, v in r.getheaders()}, r.read()
    conn.close()
    return out


def test_no_session_no_digest_is_401_with_a_digest_challenge(served):
    status, headers, _ = raw(served, "GET", "/rw/panel/ctrlstate?json=1")
    assert status == 401
    challenge = parse_challenge(headers["www-authenticate"])
    assert challenge["realm"] == REALM and "auth" in challenge["qop"] and challenge["nonce"]


def test_a_wrong_password_is_refused(served):
    rws = RwsSession(*served.address, password="not-robotics")
    with pytest.raises(RwsRefused) as err:
        rws.get("rw/panel/ctrlstate")
    assert err.value.status == 401


def test_a_session_opens_with_its_cookies_and_then_needs_no_digest(served):
    rws = RwsSession(*served.address)
    assert rws.get("rw/panel/ctrlstate")[0]["ctrlstate"] == "motoron"
    assert set(rws.cookies) == {"-http-session-", "ABBCX"}
    cookie = "; ".join(f"{k}={v}" for k, v in rws.cookies.items())
    status, headers, body = raw(served, "GET", "/rw/panel/opmode?json=1", {"Cookie": cookie})
    assert status == 200 and headers["content-type"] == "application/json"
    assert json.loads(body)["_embedded"]["_state"][0] == {"_type": "pnl-opmode", "_title": "opmode", "opmode": "AUTO"}


def test_unknown_resources_are_404_and_busy_is_503(served):
    rws = RwsSession(*served.address)
    with pytest.raises(RwsRefused) as err:
        rws.get("rw/no/such/thing")
    assert err.value.status == 404
    served.rws.busy(1)
    with pytest.raises(RwsRefused) as err:
        rws.get("rw/panel/ctrlstate")
    assert err.value.status == 503
    assert rws.get("rw/panel/ctrlstate")[0]["ctrlstate"] == "motoron"  # only the next request was refused


def test_without_json_the_answer_is_xhtml(served):
    rws = RwsSession(*served.address)
    rws.get("rw/panel/ctrlstate")  # a session
    cookie = "; ".join(f"{k}={v}" for k, v in rws.cookies.items())
    status, headers, body = raw(served, "GET", "/rw/motionsystem/mechunits/ROB_1/jointtarget", {"Cookie": cookie})
    assert status == 200 and headers["content-type"] == "application/xhtml+xml"
    assert b'<li class="ms-jointtarget" title="ROB_1"><span class="rax_1">0.000000</span>' in body


def test_the_robtarget_at_the_calibration_position_is_the_datasheets_flange(served):
    # IRB 120 product specification: at all joints 0 the flange centre is 374 mm forward, 630 mm up; tool0 then
    # points forward (z along the base x axis): a 90 deg turn about y, quaternion (cos 45, 0, sin 45, 0)
    served.controller.q = (0.0,) * 6
    item = RwsSession(*served.address).get("rw/motionsystem/mechunits/ROB_1/robtarget")[0]
    assert [float(item[k]) for k in ("x", "y", "z")] == pytest.approx([374, 0, 630], abs=1e-3)
    h = math.sqrt(0.5)
    assert [float(item[k]) for k in ("q1", "q2", "q3", "q4")] == pytest.approx([h, 0, h, 0], abs=1e-6)


@settings(max_examples=60)
@given(
    method=st.sampled_from(["GET", "POST", "PUT", "DELETE"]),
    path=st.lists(
        st.sampled_from(
            [
                "rw",
                "rapid",
                "symbol",
                "data",
                "RAPID",
                "T_ROB1",
                "TrackcalRws",
                "trackcal_move",
                "panel",
                "ctrlstate",
                "execution",
                "x",
                "%00",
                "..",
                "",
            ]
        ),
        max_size=8,
    ),
    action=st.sampled_from(["", "set", "start", "stop", "resetpp", "setctrlstate", "junk"]),
    body=st.binary(max_size=40),
)
def test_any_request_gets_an_http_answer_never_a_500(method, path, action, body):
    """Whatever a client sends with a session, the mock answers as a controller does: never an internal error, never a
    dropped connection (a RobotWare controller answers 400, 404 or 405)."""
    server = _SERVED[0]
    url = "/" + "/".join(path) + (f"?action={action}&json=1" if action else "?json=1")
    status, _, _ = raw(server, method, url, {"Cookie": _SERVED[1]}, body)
    assert status in (200, 204, 400, 404, 405)


_SERVED: list = []


@pytest.fixture(autouse=True, scope="module")
def _one_server_for_the_fuzzer():
    chain, _ = load_robot("irb120")
    server = AbbServer(AbbController(HOME), flange_of(chain), seed=9).start()
    rws = RwsSession(*server.address)
    rws.get("rw/panel/ctrlstate")
    _SERVED[:] = [server, "; ".join(f"{k}={v}" for k, v in rws.cookies.items())]
    yield
    server.stop()
