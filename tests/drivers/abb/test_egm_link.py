"""The EGM monitor (drivers/abb/egm_link.py) on loopback, without a controller: only the controller's datagrams count,
anything else from it is counted as bad, and a stream that stops is stale after stale_s."""

from __future__ import annotations

import socket
import time

import pytest

from trackcal.drivers.abb.egm_codec import EgmRobot, encode
from trackcal.drivers.abb.egm_link import EGM_STALE, EgmLink
from trackcal.drivers.errors import DeviceFault, DeviceTimeout

FRAME = encode(EgmRobot(1, 4, (1.0, 2.0, 3.0, 4.0, 5.0, 6.0), (0.0,) * 6, True, True))


def send_from(source: str, address, data: bytes) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((source, 0))
        s.sendto(data, address)


def test_only_the_controllers_egm_frames_count():
    link = EgmLink("127.0.0.1", 0, "127.0.0.1", stale_s=0.2)
    link.listen()
    try:
        send_from("127.0.0.2", link.address, FRAME)  # another sender on the network: refused
        with pytest.raises(DeviceTimeout):
            link.wait_first(0.3)
        assert [a for a, _ in link.refused] == ["127.0.0.2"]
        send_from("127.0.0.1", link.address, b"\xff\xff")  # the controller, but not an EgmRobot
        send_from("127.0.0.1", link.address, FRAME)
        link.wait_first(2.0)
        assert link.bad == 1 and link.last_seq == 1
        assert link.frames_from(1)[0][1].joints_deg == (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
        assert link.stale() is None
        time.sleep(0.3)  # no frame for longer than stale_s
        with pytest.raises(DeviceFault) as err:
            link.require_fresh()
        assert err.value.code == EGM_STALE
    finally:
        link.close()
