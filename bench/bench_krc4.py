"""The KR C4 over loopback: the RSI frame rate the mock KR C4 sustains at its nominal 4 ms cycle with KukaKrc4
answering every frame, and door-to-brake latency (the motion guard turns True -> the controller starts braking),
against the same measure for a bare client loop that polls the door as fast as it can and sends the stop request
itself (what the guard's period and the client's machinery add).

    python -m bench.bench_krc4 [--seconds 3] [--stops 5]

Printed: frames per second against 250 (IPO_FAST, kuka_rsi_hw_interface/krl/KR_C4_RSI_4+/README.md), the share of
answers the mock counted late (its budget: one cycle, 4 ms), and door-to-brake p50/max in ms and in 4 ms cycles for
both clients, with their ratio.
"""

from __future__ import annotations

import argparse
import contextlib
import socket
import statistics
import sys
import threading
import time

from bench.goals import check
from trackcal.drivers.errors import DeviceFault
from trackcal.drivers.krc4.client import KukaKrc4
from trackcal.drivers.kuka.eki_codec import KIND_STOP, Command, encode_command
from trackcal.mocks.clock import VirtualClock
from trackcal.mocks.servers.krc4.controller import KRC4_CYCLE_S, MockKrc4

HOME = (0.0, -90.0, 90.0, 0.0, 90.0, 0.0)
FAR = (20.0, -80.0, 80.0, 20.0, 80.0, 20.0)  # 20 deg from HOME: at 30 % of 60 deg/s, ~1.1 s


def _cell(guard=None):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    mock = MockKrc4(("127.0.0.1", 0), ("127.0.0.1", port), VirtualClock(real_fraction=1.0), HOME, seed=1,
                    answer_budget_s=KRC4_CYCLE_S, max_late_packages=10**9).start()  # fmt: skip
    client = KukaKrc4(mock.eki_addr[1], "127.0.0.1", port, controller_host="127.0.0.1", motion_guard=guard,
                      connect_timeout_s=10.0, move_timeout_s=60.0)  # fmt: skip
    client.connect()
    return mock, client


def frame_rate(seconds: float) -> tuple[float, float]:
    mock, client = _cell()
    try:
        n0, t0, late0 = mock.frames_sent, time.monotonic(), mock.late_packets
        time.sleep(seconds)
        frames, late = mock.frames_sent - n0, mock.late_packets - late0
        return frames / (time.monotonic() - t0), late / max(frames, 1)
    finally:
        client.close()
        mock.stop()


def _braked(mock, n: int) -> float:
    while len(mock.stops) <= n:
        time.sleep(0.0002)
    return time.monotonic()


def door_to_brake_client(stops: int) -> list[float]:
    door = threading.Event()
    mock, client = _cell(guard=lambda: "door open" if door.is_set() else None)
    out = []
    try:
        for i in range(stops):
            door.clear()
            t: list[float] = []

            def open_door(i=i, t=t):
                while not mock.moving:
                    time.sleep(0.0005)
                time.sleep(0.05)
                t.append(time.monotonic())
                door.set()
                t.append(_braked(mock, i))

            th = threading.Thread(target=open_door, daemon=True)
            th.start()
            with contextlib.suppress(DeviceFault):
                client.move(FAR if i % 2 == 0 else HOME, 30)
            th.join()
            out.append(t[1] - t[0])
            door.clear()
            client.move(FAR if i % 2 == 0 else HOME, 100)
    finally:
        client.close()
        mock.stop()
    return out


def door_to_brake_bare(stops: int) -> list[float]:
    """The bare loop: a move request, then poll the door flag and send the stop request on the EKI socket."""
    mock, client = _cell()
    sock = client.eki._sock
    out = []
    try:
        for i in range(stops):
            command_id = 1000 + i
            sock.sendall(encode_command(Command(command_id, 1, FAR if i % 2 == 0 else HOME, 30)))
            while not mock.moving:
                time.sleep(0.0005)
            time.sleep(0.05)
            t0 = time.monotonic()  # the door opens: a bare loop sends the stop request at once
            sock.sendall(encode_command(Command(command_id, KIND_STOP)))
            out.append(_braked(mock, i) - t0)
            # as the guarded client does after its stop: the full move to the target, so the next one is long too
            time.sleep(0.2)
            sock.sendall(encode_command(Command(command_id + 500, 1, FAR if i % 2 == 0 else HOME, 100)))
            time.sleep(0.05)
            while mock.moving:
                time.sleep(0.001)
            sock.settimeout(0.5)
            with contextlib.suppress(TimeoutError):
                while sock.recv(4096):  # drain what the mock still sends: each read is the loop's work
                    continue
    finally:
        client.close()
        mock.stop()
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--stops", type=int, default=5)
    a = ap.parse_args(argv or [])
    rate, late = frame_rate(a.seconds)
    nominal = 1 / KRC4_CYCLE_S
    print(f"RSI frames/s {rate:.0f} of {nominal:.0f} nominal ({rate / nominal:.2f}x), late answers {late:.2%}")
    check("KR C4 mock sustains >= 90 % of 250 frames/s with KukaKrc4 answering", f"{rate:.0f}/s",
          rate >= 0.9 * nominal)  # fmt: skip
    client = door_to_brake_client(a.stops)
    bare = door_to_brake_bare(a.stops)
    for name, v in (("KukaKrc4 guard", client), ("bare loop", bare)):
        print(f"door -> brake, {name}: p50 {statistics.median(v) * 1e3:.1f} ms, max {max(v) * 1e3:.1f} ms "
              f"({max(v) / KRC4_CYCLE_S:.1f} cycles)")  # fmt: skip
    print(f"ratio client / bare (p50): {statistics.median(client) / statistics.median(bare):.1f}x")
    # issue 40: the guard stops the robot within a cycle or two; the client polls it every GUARD_S (40 ms)
    check("KR C4 door -> brake within 2 RSI cycles (8 ms), KukaKrc4 guard", f"max {max(client) * 1e3:.1f} ms",
          max(client) <= 2 * KRC4_CYCLE_S)  # fmt: skip


if __name__ == "__main__":
    main(sys.argv[1:])
