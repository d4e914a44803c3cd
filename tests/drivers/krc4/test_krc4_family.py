"""The krc4 family as drivers/families.py finds it: a KR C4 cell's compensated program is KRL from the one KRL writer,
and the device list names the controller it connects to and the port it listens on."""

from trackcal.drivers.families import families


def test_the_kr_c4_writes_krl_with_the_kr_c2_writer():
    found = families()
    assert found["krc4"].program is found["krc2"].program and found["krc4"].program.language == "KRL"
    assert found["krc4"].readers is None  # the KRL reader is registered once, by the kuka family


def test_the_device_line_says_who_serves_and_who_listens():
    r = {
        "controller_host": "192.168.1.20",
        "eki": {"port": 54600},
        "connect_timeout_s": 60.0,
        "rsi": {"host": "192.168.1.10", "port": 49152, "passive": False, "cycle_s": 0.004},
    }
    family = families()["krc4"]
    assert family.describe(r) == ("KR C4, EKI at 192.168.1.20:54600, RSI udp (answered, 4 ms) on 192.168.1.10:49152")
    assert "start trackcal_eki" in family.waiting(r) and family.dof == 6
