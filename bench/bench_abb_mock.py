"""The mock ABB controller (issue 40), in its own process.

1. EGM frame rate it sustains: one receiver of its EgmRobot stream (one per 4 ms tick: 250 Hz) for `--seconds` of wall
   time. Printed: frames per wall second, and the frames due by the header's sequence numbers (a lost one shows as a
   gap).
2. Door-open to RAPID's stop request: a flag set mid-move (the door), and the time until the stop POST leaves this
   process, for trackcal (AbbRws.move: the guard asked before every RWS request and every 10 ms between polls)
   against a bare loop with no trackcal code (the same RWS session class polling trackcal_done every 10 ms and the
   flag between), `--trials` of each, interleaved. Printed: median and p99 of each, and their ratio.

    python -m bench.bench_abb_mock [--seconds 3] [--trials 10]
"""

from __future__ import annotations

import argparse
import contextlib
import socket
import sys
import threading
import time

import numpy as np

from bench.goals import check
from trackcal.drivers.abb.client import AbbRws
from trackcal.drivers.abb.egm_codec import decode
from trackcal.drivers.abb.program import MOVE, SPEED, TARGET, joint_value, symbol_path
from trackcal.drivers.abb.rws import RwsSession
from trackcal.drivers.errors import DeviceFault
from trackcal.mocks.servers.abb.process import MockAbbProcess

RATE_HZ = 250.0  # one EgmRobot per 4 ms tick
TARGETS = ((100.0, 0.0, 0.0, 0.0, 30.0, 0.0), (-100.0, 0.0, 0.0, 0.0, 30.0, 0.0))
OPEN_AFTER_S = 0.15


def egm_rate(seconds: float) -> tuple[int, float, int]:
    """(frames received, wall seconds, frames due by their sequence numbers)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        s.settimeout(1.0)
        port = s.getsockname()[1]
        with MockAbbProcess(seed=0, args=["--egm", f"127.0.0.1:{port}"]):
            seqs = []
            t0 = time.monotonic()
            while time.monotonic() - t0 < seconds:
                seqs.append(decode(s.recv(65536)).seqno)
            wall = time.monotonic() - t0
    return len(seqs), wall, seqs[-1] - seqs[0] + 1


def trackcal_trial(robot: AbbRws, target) -> float | None:
    """None when the door opened before the move was sent (refused, nothing to stop)."""
    door: dict[str, float] = {}
    robot.motion_guard = lambda: "door open" if door else None
    threading.Timer(OPEN_AFTER_S, lambda: door.setdefault("t", time.monotonic())).start()
    with contextlib.suppress(DeviceFault):  # the stop ends the move in DeviceFault: that is the trial
        robot.move(target, 20)
    robot.motion_guard = None
    robot.reset_faults()
    sent = robot.stop_sent_at
    return None if sent is None or sent < door["t"] else sent - door["t"]


def bare_trial(rws: RwsSession, target, number: int) -> float:
    """Write the move, poll its answer every 10 ms and the door between, POST the stop: no trackcal client code."""
    door: dict[str, float] = {}
    rws.post(symbol_path(TARGET), {"action": "set"}, {"value": joint_value(target)})
    rws.post(symbol_path(SPEED), {"action": "set"}, {"value": "20"})
    rws.post(symbol_path(MOVE), {"action": "set"}, {"value": str(number)})
    threading.Timer(OPEN_AFTER_S, lambda: door.setdefault("t", time.monotonic())).start()
    while not door:
        rws.get(symbol_path("trackcal_done"))
        time.sleep(0.01)
    sent = time.monotonic()
    rws.post("rw/rapid/execution", {"action": "stop"}, {"stopmode": "stop"})
    return sent - door["t"]


def door_latency(trials: int) -> dict[str, list[float]]:
    out: dict[str, list[float]] = {"trackcal": [], "bare": []}
    with MockAbbProcess(seed=1) as mock:
        robot = AbbRws(*mock.address)
        robot.connect()
        for k in range(trials):
            latency = trackcal_trial(robot, TARGETS[k % 2])
            if latency is not None:
                out["trackcal"].append(latency)
            time.sleep(0.3)
            number = int(mock.state()["pers"][MOVE]) + 1
            out["bare"].append(bare_trial(robot.rws, TARGETS[(k + 1) % 2], number))
            time.sleep(0.3)
            robot.reset_faults()  # RAPID from main again, the bare loop's move dropped
            robot._next = number + 1  # the bare loop used a move number: the client's next one follows it
        robot.close()
    return out


def _ms(values: list[float]) -> tuple[float, float]:
    a = np.asarray(values) * 1000
    return float(np.median(a)), float(np.percentile(a, 99))


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--seconds", type=float, default=3.0)
    p.add_argument("--trials", type=int, default=10)
    args = p.parse_args(argv or [])
    n, wall, due = egm_rate(args.seconds)
    rate = n / wall
    verdict = check(
        "ABB mock EGM 250 Hz: >= 90 % of the rate, no frame lost",
        f"{rate:.1f} frames/s, {n} received of {due} due",
        rate >= 0.9 * RATE_HZ and n == due,
    )
    print(
        f"EGM: {n} frames in {wall:.2f} s = {rate:.1f} frames/s; {due} due by their sequence numbers; {verdict}",
        flush=True,
    )
    lat = door_latency(args.trials)
    (tm, tp), (bm, bp) = _ms(lat["trackcal"]), _ms(lat["bare"])
    verdict = check(
        "ABB door open -> RAPID stop sent: trackcal's median <= 1.5x a bare RWS loop's",
        f"trackcal {tm:.1f} ms (p99 {tp:.1f}), bare {bm:.1f} ms (p99 {bp:.1f}), ratio {tm / bm:.2f}",
        tm <= 1.5 * bm,
    )
    print(
        f"door open -> RAPID stop sent, {len(lat['trackcal'])} and {args.trials} of {args.trials} interleaved "
        f"trials (a door opened before trackcal sent its move needs no stop): trackcal median {tm:.2f} ms, p99 "
        f"{tp:.2f} ms; bare RWS loop median {bm:.2f} ms, p99 {bp:.2f} ms; ratio {tm / bm:.2f}; {verdict}",
        flush=True,
    )


if __name__ == "__main__":
    main(sys.argv[1:])
