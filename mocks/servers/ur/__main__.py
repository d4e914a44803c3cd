"""python -m trackcal.mocks.servers.ur --host 127.0.0.N --seed S [...]: the mock UR controller in this process.

Serves until killed or told `quit` on its control port. Every mistake (a bad option, an address it cannot bind)
ends in one line on stderr and exit code 2."""

from __future__ import annotations

import argparse
import math
import sys

from trackcal.mocks.servers.main import OneLineParser, joints_deg, serve, six_axis_chain
from trackcal.mocks.servers.ur.controller import HOME_RAD, UrController
from trackcal.mocks.servers.ur.server import CONTROL_PORT, UrServer


def _joints(text: str) -> tuple[float, ...]:
    return tuple(math.radians(v) for v in joints_deg(text))


def _version(text: str) -> tuple[int, int, int, int]:
    parts = text.split(".")
    if len(parts) != 4 or not all(p.isdigit() for p in parts):
        raise argparse.ArgumentTypeError(f"expected MAJOR.MINOR.BUGFIX.BUILD, got {text!r}")
    return tuple(int(p) for p in parts)  # type: ignore[return-value]


def parser() -> argparse.ArgumentParser:
    p = OneLineParser(
        prog="python -m trackcal.mocks.servers.ur",
        description="Mock Universal Robots e-Series controller (RTDE 30004, dashboard 29999, "
        "script ports 30001-30003) on one address.",
    )
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    p.add_argument("--robot", default="ur10", help="robot model of configs/robots (joint limits; default ur10)")
    p.add_argument("--seed", type=int, default=0, help="serial number, factory calibration, timestamps (default 0)")
    p.add_argument("--q0-deg", type=_joints, default=HOME_RAD, help="initial joints, 6 comma-separated deg")
    p.add_argument(
        "--version",
        type=_version,
        default=(5, 11, 1, 108318),
        help="controller / PolyScope version MAJOR.MINOR.BUGFIX.BUILD (default 5.11.1.108318)",
    )
    p.add_argument(
        "--unlock-delay-s",
        type=float,
        default=5.0,
        help="least time between a protective stop and its unlock (default 5, as the real one)",
    )
    p.add_argument("--local", action="store_true", help="not in remote control (refuses remote-only commands)")
    p.add_argument("--powered-off", action="store_true", help="start in POWER_OFF (power on + brake release)")
    p.add_argument(
        "--protective-stop-on-move",
        type=int,
        default=0,
        metavar="N",
        help="a protective stop halfway through the N-th movej, with it if the arm stands at its target (0: never)",
    )
    p.add_argument(
        "--drop-on-move", type=int, default=0, metavar="N", help="drop every connection halfway through the N-th movej"
    )
    p.add_argument(
        "--stale-on-move",
        type=int,
        default=0,
        metavar="N",
        help="stop sending RTDE frames halfway through the N-th movej (connections stay open)",
    )
    p.add_argument(
        "--unreachable-on-move",
        type=int,
        default=0,
        metavar="N",
        help="halfway through the N-th movej, close every connection and refuse new ones for --unreachable-s",
    )
    p.add_argument("--unreachable-s", type=float, default=10.0, help="seconds unreachable (default 10)")
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        help="controller seconds per wall second (default 1; faster sends fewer frames, each of its own tick)",
    )
    p.add_argument(
        "--control-port",
        type=int,
        default=CONTROL_PORT,
        help=f"the mock's fault-injection / state port (default {CONTROL_PORT})",
    )
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    for name, value, ok in (
        ("--unlock-delay-s", args.unlock_delay_s, args.unlock_delay_s >= 0),
        ("--unreachable-s", args.unreachable_s, 0 <= args.unreachable_s <= 3600),
        ("--speed", args.speed, 0 < args.speed <= 100),
    ):
        if not ok or not math.isfinite(value):
            print(f"{parser().prog}: error: {name} out of range: {value}", file=sys.stderr)
            return 2
    chain = six_axis_chain(parser().prog, args.robot, "a UR has 6")
    if chain is None:
        return 2
    limits = [(float(lo), float(hi)) for lo, hi in chain.limits_array()]
    ctl = UrController(
        seed=args.seed,
        q0=args.q0_deg,
        version=args.version,
        unlock_delay_s=args.unlock_delay_s,
        remote_control=not args.local,
        limits=limits,
        powered=not args.powered_off,
        protective_stop_on_move=args.protective_stop_on_move,
    )
    if args.drop_on_move:
        ctl.fault_on_move[args.drop_on_move] = "drop"
    if args.stale_on_move:
        ctl.fault_on_move[args.stale_on_move] = "stale"
    if args.unreachable_on_move:
        ctl.fault_on_move[args.unreachable_on_move] = f"unreachable {args.unreachable_s}"
    server = UrServer(ctl, args.host, args.control_port, speed=args.speed)
    try:
        server.start()
    except OSError as exc:
        print(f"{parser().prog}: error: cannot serve on {args.host}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    return serve(server)


if __name__ == "__main__":
    sys.exit(main())
