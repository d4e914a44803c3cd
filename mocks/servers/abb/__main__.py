"""python -m trackcal.mocks.servers.abb --host 127.0.0.N --port P --control-port C [...]: the mock ABB controller
(IRC5, RobotWare 6: Robot Web Services) in this process, serving until told `quit` on its control port or SIGTERM.
When both ports are bound it prints one line `ready RWS_PORT CONTROL_PORT` on stdout (process.py waits for it).
Every mistake (a bad option, an address it cannot bind) ends in one line on stderr and exit code 2."""

from __future__ import annotations

import argparse
import math
import sys

from trackcal.mocks.servers.abb.controller import AbbController
from trackcal.mocks.servers.abb.rws_server import flange_of
from trackcal.mocks.servers.abb.server import AbbServer
from trackcal.mocks.servers.main import OneLineParser, joints_deg, serve, six_axis_chain

HOME_DEG = (0.0, 0.0, 0.0, 0.0, 30.0, 0.0)  # a standing IRB 120 clear of the axis-5 singularity


def _address(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host, int(port)


def parser() -> argparse.ArgumentParser:
    p = OneLineParser(
        prog="python -m trackcal.mocks.servers.abb",
        description="Mock ABB IRC5 controller (RobotWare 6 Robot Web Services) on one address.",
    )
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=0, help="RWS HTTP port (default 0: a free one)")
    p.add_argument("--control-port", type=int, default=0, help="the mock's control port (default 0: a free one)")
    p.add_argument("--robot", default="irb120", help="robot model of configs/robots (default irb120)")
    p.add_argument("--seed", type=int, default=0, help="serial number and session tokens (default 0)")
    p.add_argument("--q0-deg", type=joints_deg, default=HOME_DEG, help="initial joints, 6 comma-separated deg")
    p.add_argument("--speed", type=float, default=1.0, help="controller seconds per wall second (default 1)")
    p.add_argument(
        "--egm",
        type=_address,
        default=None,
        metavar="HOST:PORT",
        help="stream EGM (UDP, one EgmRobot per 4 ms tick) to the sensor at HOST:PORT (default: none)",
    )
    p.add_argument("--motors-off", action="store_true", help="start with the motors off and RAPID stopped")
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    prog = parser().prog
    if not (math.isfinite(args.speed) and 0 < args.speed <= 100):
        print(f"{prog}: error: --speed out of range 0..100: {args.speed}", file=sys.stderr)
        return 2
    chain = six_axis_chain(prog, args.robot, "the mock drives 6")
    if chain is None:
        return 2
    controller = AbbController(args.q0_deg, seed=args.seed)
    if not args.motors_off:
        controller.set_ctrlstate("motoron")
        controller.start()
    try:
        server = AbbServer(
            controller,
            flange_of(chain),
            args.host,
            args.port,
            args.control_port,
            seed=args.seed,
            speed=args.speed,
            egm=args.egm,
        ).start()
    except OSError as exc:
        print(f"{prog}: error: cannot serve on {args.host}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    return serve(server, ready=f"ready {server.address[1]} {server.control_address[1]}")


if __name__ == "__main__":
    sys.exit(main())
