"""What the mock controllers' `python -m` entry points share (mocks/servers/abb/__main__.py,
mocks/servers/ur/__main__.py): a parser whose mistakes end in one line and exit 2, the joints option, the robot
model they drive, and serving until `quit` or SIGTERM."""

from __future__ import annotations

import argparse
import math
import signal
import sys

from trackcal.calib.model.cell import CellError, load_robot
from trackcal.calib.model.chain import Chain, ChainError


class OneLineParser(argparse.ArgumentParser):
    def error(self, message: str):  # one line, exit 2 (the house rule; argparse prints its usage too)
        self.exit(2, f"{self.prog}: error: {message}\n")


def joints_deg(text: str) -> tuple[float, ...]:
    """An option's 6 comma-separated finite joint values in degrees (argparse's type)."""
    try:
        q = tuple(float(v) for v in text.split(","))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected 6 comma-separated numbers (deg), got {text!r}") from exc
    if len(q) != 6 or not all(math.isfinite(v) for v in q):
        raise argparse.ArgumentTypeError(f"expected 6 comma-separated finite numbers (deg), got {text!r}")
    return q


def six_axis_chain(prog: str, robot: str, why: str) -> Chain | None:
    """The chain of configs/robots' `robot`, or None once one line on stderr said why not (`why`: a 6-axis mock)."""
    try:
        chain, _ = load_robot(robot)
    except (CellError, ChainError, OSError) as exc:
        print(f"{prog}: error: --robot {robot}: {exc}", file=sys.stderr)
        return None
    if chain.dof != 6:
        print(f"{prog}: error: --robot {robot} has {chain.dof} joints, {why}", file=sys.stderr)
        return None
    return chain


def serve(server, ready: str | None = None) -> int:
    """Serve until told `quit` or SIGTERM (Ctrl-C too); `ready`, when given, printed once on stdout first."""
    signal.signal(signal.SIGTERM, lambda *_: server.stop())
    if ready is not None:
        print(ready, flush=True)
    try:
        server.wait()
    except KeyboardInterrupt:
        server.stop()
    return 0
