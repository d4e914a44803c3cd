"""The mock UR controller (issue 21), in its own process.

1. RTDE frame rate it sustains: one client reading every frame of a recipe (timestamp, actual_q, actual_TCP_pose,
   robot_mode, safety_status_bits, runtime_state) at 125 Hz and at 500 Hz for `--seconds` of wall time. Printed:
   frames received per wall second, and the frames the controller's own timestamps say were due (a frame lost or
   skipped shows as a timestamp gap).
2. Door-open to stop: the cell door (the mock Modbus PLC) opened mid-move, and the time until the stopJ command is
   taken by the mock controller's cycle (its CLOCK_MONOTONIC stamp, the clock this process reads too), for trackcal
   (UrRtde.move with campaign/cells/checks.motion_guard: door and PLC status read, then the RTDE sample, every
   POLL_S) against a bare loop with no trackcal code (pymodbus reading the door input, ur_rtde's
   RTDEReceiveInterface.getActualQ, stopJ on the door; same poll period, the same ur_rtde interfaces), `--trials`
   of each, interleaved (ABAB...). Printed: median and p99 of each, and their ratio.

    python -m bench.bench_ur_mock [--seconds 5] [--trials 30] [--host 127.0.0.120]
"""

from __future__ import annotations

import argparse
import contextlib
import math
import socket
import struct
import sys
import threading
import time

import numpy as np
from pymodbus.client import ModbusTcpClient

from bench.goals import check
from trackcal.campaign.cells.checks import motion_guard
from trackcal.drivers.errors import DeviceFault
from trackcal.drivers.interfaces import RealClock
from trackcal.drivers.plc.client import ModbusCellIO
from trackcal.drivers.plc.codec import PlcRegisterMap
from trackcal.drivers.ur.client import POLL_S, UrRtde
from trackcal.mocks.servers.plc import MockPlc
from trackcal.mocks.servers.ur import rtde_codec as rc
from trackcal.mocks.servers.ur.controller import STOPJ
from trackcal.mocks.servers.ur.process import MockUrProcess
from trackcal.mocks.servers.ur.server import RTDE_PORT

NAMES = ("timestamp", "actual_q", "actual_TCP_pose", "robot_mode", "safety_status_bits", "runtime_state")


def measure(host: str, frequency: float, seconds: float) -> tuple[int, float, int]:
    """(frames received, wall seconds, frames due by the controller's timestamps)."""
    s = socket.create_connection((host, RTDE_PORT), timeout=5.0)
    deframer = rc.Deframer()
    pending: list[tuple[int, bytes]] = []

    def ask(command: int, payload: bytes = b"") -> bytes:
        s.sendall(rc.pack(command, payload))
        while True:
            pending.extend(deframer.feed(s.recv(65536)))
            for i, (cmd, body) in enumerate(pending):
                if cmd == command:
                    del pending[: i + 1]
                    return body

    ask(rc.REQUEST_PROTOCOL_VERSION, struct.pack(">H", 2))
    answer = ask(rc.CONTROL_PACKAGE_SETUP_OUTPUTS, struct.pack(">d", frequency) + ",".join(NAMES).encode())
    recipe = rc.Recipe(answer[0], NAMES, tuple(answer[1:].decode().split(",")), frequency)
    stamp = struct.Struct(">Bd")
    ask(rc.CONTROL_PACKAGE_START)
    first = last = None
    n = 0
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        for cmd, body in deframer.feed(s.recv(65536)):
            if cmd == rc.DATA_PACKAGE and body[0] == recipe.id:
                ts = stamp.unpack_from(body)[1]
                first = ts if first is None else first
                last, n = ts, n + 1
    wall = time.monotonic() - t0
    s.close()
    due = round((last - first) * frequency) + 1 if first is not None and last is not None else 0
    return n, wall, due


# two far joint targets (deg): a move between them lasts a few seconds, the door opens OPEN_AFTER_S into it
TARGETS = ((60.0, -60.0, 60.0, -60.0, -60.0, 60.0), (-60.0, -100.0, 100.0, -100.0, -100.0, -60.0))
OPEN_AFTER_S = 0.15


def _stop_taken_at(ur: MockUrProcess, after: float) -> float | None:
    """The mock's CLOCK_MONOTONIC stamp of the first STOPJ it took after `after` (None: no stop was needed, the door
    opened before the move began and the move was refused)."""
    state = ur.state()
    return min(
        (
            t
            for c, t in zip(
                state["commands"][-len(state["command_monotonic"]) :], state["command_monotonic"], strict=True
            )
            if c == STOPJ and t >= after
        ),
        default=None,
    )


def _bare_move(robot: UrRtde, modbus: ModbusTcpClient, target, door_di: int, unit: int) -> None:
    """The bare loop: ur_rtde's own interfaces and pymodbus, no trackcal code between the door and stopJ."""
    rcv, ctl = robot.receive, robot.control
    ctl.moveJ(
        [math.radians(v) for v in target],
        math.radians(robot.joint_speed_deg_s),
        math.radians(robot.joint_acceleration_deg_s2),
        True,
    )
    while True:
        closed = modbus.read_discrete_inputs(door_di, count=1, device_id=unit).bits[0]
        rcv.getActualQ()
        if not closed:
            ctl.stopJ(math.radians(robot.stop_deceleration_deg_s2), False)
            return
        time.sleep(POLL_S)


def _open_door(plc: MockPlc, opened: list[float]) -> None:
    time.sleep(OPEN_AFTER_S)
    opened.append(time.monotonic())
    plc.open_door()


def door_latency(host: str, trials: int) -> dict[str, list[float]]:
    """Door-open -> stopJ taken by the mock controller (s), `trials` each of trackcal and the bare loop, interleaved."""
    out: dict[str, list[float]] = {"trackcal": [], "bare": []}
    regs = PlcRegisterMap()
    plc = MockPlc(clock=RealClock()).start()
    plc.close_door()
    cellio = ModbusCellIO(*plc.address, timeout_s=2.0)
    cellio.connect()
    modbus = ModbusTcpClient(plc.address[0], port=plc.address[1], timeout=2.0)
    modbus.connect()
    try:
        with MockUrProcess(host, seed=0) as ur:
            robot = UrRtde(host, motion_guard=motion_guard(cellio), connect_timeout_s=20.0)
            robot.connect()
            try:
                robot.move(TARGETS[0], 100)
                for k in range(2 * trials):
                    which = ("trackcal", "bare")[k % 2]
                    target = TARGETS[(k // 2 + 1) % 2]
                    opened: list[float] = []
                    opener = threading.Thread(target=_open_door, args=(plc, opened))
                    opener.start()
                    if which == "trackcal":
                        with contextlib.suppress(DeviceFault):  # "the cell door opened": the stop asked for
                            robot.move(target, 100)
                    else:
                        _bare_move(robot, modbus, target, regs.door_closed_di, 1)
                    opener.join()
                    taken = _stop_taken_at(ur, opened[0])
                    if taken is not None:  # else the loaded machine opened the door before the move began
                        out[which].append(taken - opened[0])
                    time.sleep(0.1)  # the arm stands
                    plc.close_door()
            finally:
                robot.close()
    finally:
        modbus.close()
        cellio.close()
        plc.stop()
    return out


def _ms(values: list[float]) -> tuple[float, float]:
    """(median, p99) in ms."""
    a = 1000.0 * np.asarray(values)
    return float(np.median(a)), float(np.percentile(a, 99))


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--seconds", type=float, default=5.0)
    p.add_argument("--host", default="127.0.0.120")
    p.add_argument("--trials", type=int, default=30)
    args = p.parse_args(argv or [])
    with MockUrProcess(args.host, seed=0):
        for frequency in (125.0, 500.0):
            n, wall, due = measure(args.host, frequency, args.seconds)
            rate = n / wall
            ok = rate >= 0.9 * frequency and n == due
            verdict = check(
                f"UR mock RTDE {frequency:.0f} Hz: >= 90 % of the rate, no frame lost",
                f"{rate:.1f} frames/s, {n} received of {due} due",
                ok,
            )
            print(
                f"RTDE {frequency:5.0f} Hz: {n} frames in {wall:.2f} s = {rate:.1f} frames/s; "
                f"{due} due by the controller's timestamps; {verdict}",
                flush=True,
            )

    lat = door_latency(args.host, args.trials)
    (tm, tp), (bm, bp) = _ms(lat["trackcal"]), _ms(lat["bare"])
    # the goal is a ratio of interleaved runs (absolute milliseconds follow the machine's load): trackcal's guard (the
    # door and the PLC status word, two Modbus reads) and its sample add at most half again the bare loop's median
    verdict = check(
        "UR door open -> stopJ at the controller: trackcal's median <= 1.5x a bare ur_rtde loop's",
        f"trackcal {tm:.1f} ms (p99 {tp:.1f}), bare {bm:.1f} ms (p99 {bp:.1f}), ratio {tm / bm:.2f}",
        tm <= 1.5 * bm,
    )
    print(
        f"door open -> stopJ taken by the mock UR, {len(lat['trackcal'])} and {len(lat['bare'])} of {args.trials} "
        "interleaved trials (a door opened before its move began needs no stop): trackcal median "
        f"{tm:.2f} ms, p99 {tp:.2f} ms; bare ur_rtde + pymodbus loop median {bm:.2f} ms, p99 {bp:.2f} ms; "
        f"ratio of medians {tm / bm:.2f}; {verdict}",
        flush=True,
    )


if __name__ == "__main__":
    main(sys.argv[1:])
