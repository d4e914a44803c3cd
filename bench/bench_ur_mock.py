"""RTDE frame rate the mock UR controller sustains (issue 21): the mock in its own process, one client reading
every frame of a recipe (timestamp, actual_q, actual_TCP_pose, robot_mode, safety_status_bits, runtime_state) at
125 Hz and at 500 Hz for `--seconds` of wall time. Printed: frames received per wall second, and the frames the
controller's own timestamps say were due (a frame lost or skipped shows as a timestamp gap).

    python -m bench.bench_ur_mock [--seconds 5] [--host 127.0.0.120]
"""

from __future__ import annotations

import argparse
import socket
import struct
import time

from bench.goals import check
from trackcal.mocks.servers.ur import rtde_codec as rc
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


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--seconds", type=float, default=5.0)
    p.add_argument("--host", default="127.0.0.120")
    args = p.parse_args(argv or [])
    with MockUrProcess(args.host, seed=0):
        for frequency in (125.0, 500.0):
            n, wall, due = measure(args.host, frequency, args.seconds)
            rate = n / wall
            ok = rate >= 0.9 * frequency and n == due
            verdict = check(f"UR mock RTDE {frequency:.0f} Hz: >= 90 % of the rate, no frame lost",
                            f"{rate:.1f} frames/s, {n} received of {due} due", ok)  # fmt: skip
            print(f"RTDE {frequency:5.0f} Hz: {n} frames in {wall:.2f} s = {rate:.1f} frames/s; "
                  f"{due} due by the controller's timestamps; {verdict}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
