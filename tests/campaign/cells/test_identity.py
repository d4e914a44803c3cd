"""The devices' identities at a run's start (#39, campaign/cells/identity.py): recorded as an `identity` document, the
tracker's serial compared with the hardware file's (a mismatch warns in one line), a device that cannot say who it is
recorded as such; the KR C2 and KR C4, whose EKI and RSI offer no identity query, take theirs from the hardware file.
Serial numbers and versions here are made-up labels: only their equality matters."""

import json

import pytest

from trackcal.campaign.cells.hardware import load_hardware
from trackcal.campaign.cells.identity import IdentityCheck, serial_matches
from trackcal.campaign.engine.engine import Document, Live, RunContext
from trackcal.drivers.errors import DeviceFault
from trackcal.drivers.interfaces import FROM_HARDWARE_FILE, READ_FROM_DEVICE, DeviceIdentity

TRACKER = DeviceIdentity("390123", "AT901-LR (ES_LTSensorType 15)", "LCP firmware 3.6, emScon 3.6.0", READ_FROM_DEVICE)
ROBOT = DeviceIdentity("", "KUKA KR C2", "", FROM_HARDWARE_FILE)


class Says:
    """A device whose identity() returns `identity` or raises it."""

    def __init__(self, identity):
        self._identity = identity

    def identity(self):
        if isinstance(identity := self._identity, Exception):
            raise identity
        return identity


def run_start(tracker, stated: dict | None) -> list[Document]:
    """The documents of a run's start with IdentityCheck last among the subscribers, as run_session places it."""
    seen: list[Document] = []
    context = RunContext([seen.append])
    live = Live(Says(tracker), Says(ROBOT), None, None)  # type: ignore[arg-type]  (only identity() is asked)
    context.subscribers.append(IdentityCheck(live, context.emit, stated))
    context.emit("start", {"resumed": False, "steps": 1, "done": 0})
    return seen


@pytest.mark.parametrize(
    "stated, read, same",
    [
        ("390123", "390123", True),
        ("AT901-390123", "390123", True),
        ("at901 390123", "390123", True),
        ("AT901-000000", "390123", False),
        ("390124", "390123", False),
        ("AT901", "390123", False),
    ],
)
def test_a_stated_serial_names_the_number_the_tracker_reports(stated, read, same):
    assert serial_matches(stated, read) is same


def test_the_identity_is_recorded_and_a_serial_the_file_does_not_state_warns():
    docs = run_start(TRACKER, {"serial": "AT901-000000", "certificate": "CAL-2026-7"})
    assert [d.name for d in docs] == ["start", "identity", "warning"]
    assert docs[1].data == {
        "tracker": {
            "serial": "390123",
            "model": TRACKER.model,
            "software": TRACKER.software,
            "source": "read from the device",
        },
        "robot": {"serial": "", "model": "KUKA KR C2", "software": "", "source": "from the hardware file"},
    }
    json.dumps(docs[1].data, allow_nan=False)  # strict JSON, as the store writes it
    message = docs[2].data["message"]
    assert "\n" not in message and "390123" in message and "AT901-000000" in message and "CAL-2026-7" in message


@pytest.mark.parametrize("stated", [{"serial": "AT901-390123"}, {"certificate": "CAL-1"}, None])
def test_no_warning_when_the_serials_agree_or_one_side_says_nothing(stated):
    assert [d.name for d in run_start(TRACKER, stated)] == ["start", "identity"]


def test_a_tracker_that_cannot_say_who_it_is_is_recorded_so_and_the_run_goes_on():
    refused = DeviceFault(
        "command not implemented by this tracker/server while reading the tracker's identity",
        code=2,
        device="tracker 127.0.0.1:700",
    )
    docs = run_start(refused, {"serial": "AT901-000000"})
    assert [d.name for d in docs] == ["start", "identity"]
    assert "not implemented" in docs[1].data["tracker"]["error"]


def test_a_certificate_past_its_due_date_warns_at_the_start():
    """Due dates far from any day the suite runs on: 2019-12-31 has passed, 2999-12-31 has not."""
    docs = run_start(TRACKER, {"serial": "390123", "certificate": "CAL-2019-1", "certificate_due": "2019-12-31"})
    assert [d.name for d in docs] == ["start", "identity", "warning"]
    message = docs[2].data["message"]
    assert "CAL-2019-1 was due on 2019-12-31" in message and "--accept-expired-certificate" in message
    assert len(run_start(TRACKER, {"serial": "390123", "certificate_due": "2999-12-31"})) == 2


def test_only_the_start_reads_the_identities():
    seen: list[Document] = []
    context = RunContext([seen.append])
    context.subscribers.append(IdentityCheck(Live(Says(TRACKER), Says(ROBOT), None, None), context.emit, None))  # type: ignore[arg-type]
    context.emit("warning", {"message": "x"})
    assert [d.name for d in seen] == ["warning"]


HARDWARE = """
tracker: {protocol: emscon, host: 192.168.0.10}
robot:
  protocol: %s
  controller_host: 192.168.0.5
  eki: {%s}
  rsi: {host: 192.168.0.2, port: 49152}
  serial: "KR-0123456"
  software: "KSS 8.6.9"
"""


@pytest.mark.parametrize(
    "protocol, eki, model",
    [
        ("krc2", "host: 192.168.0.2, port: 54600", "KUKA KR C2"),
        ("krc4", "port: 54600", "KUKA KR C4"),
    ],
)
def test_kuka_controllers_take_their_identity_from_the_hardware_file(tmp_path, protocol, eki, model):
    path = tmp_path / "hw.yaml"
    path.write_text(HARDWARE % (protocol, eki))
    hw = load_hardware(path)
    robot = hw.family.build(hw.robot, joint_limits_deg=((-180.0, 180.0),) * 6, cell_box_check=None, motion_guard=None)
    try:
        assert robot.identity() == DeviceIdentity("KR-0123456", model, "KSS 8.6.9", FROM_HARDWARE_FILE)
    finally:
        robot.close()
