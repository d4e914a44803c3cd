"""`trackcal mock`: the digital twin's cell as a stand-alone set of devices, for `trackcal run --hardware`.

    trackcal mock --cell kr270 --seed 3 --write-hardware cell.yaml &
    trackcal run --cell kr270 --plan plan.json --hardware cell.yaml --session sessions/a

The mocks of `run --sim` (campaign.cells.sim.TwinMocks) on free loopback ports of this process: emScon tracker,
Modbus cell PLC with the simulated operator at its lamp (he reads the HMI request registers, the only channel
between the processes), serial meteo on a pseudo-terminal, and the KR C2, which like the real controller
connects to the EKI and RSI ports trackcal listens on (two free ports chosen here and written into the
hardware file), retrying until trackcal is there and starting afresh whenever trackcal goes away, so several
`run` / `resume` in a row each find a controller. Serves until SIGINT or SIGTERM, then exits 0.

Unlike `run --sim`, the twin does not know the session: the n-th measurement of a (station, point, pose)
counts from this mock's start, so a resumed campaign's noise is not that of an uninterrupted one.
"""

from __future__ import annotations

import os
import signal
import socket
import threading
from pathlib import Path

import yaml
from rich.table import Table

from trackcal.calib.io.files import write_text
from trackcal.calib.model.cell import load_cell
from trackcal.campaign.cells.sim import CONTROLLER_CONNECT_S, TwinMocks, free_port, hardware_doc, krc2_robot_doc
from trackcal.campaign.cli.console import console
from trackcal.campaign.errors import InputError, UsageError
from trackcal.campaign.jobs.simulate import parse_effects


def cmd_mock(args) -> int:
    effects = parse_effects(args.effect)
    if args.sim_speed is not None and not args.sim_speed > 0:
        raise UsageError("--sim-speed must be positive (simulated seconds per real second)")
    cell = load_cell(args.cell)
    out = Path(args.write_hardware) if args.write_hardware else None
    if out is not None and out.is_dir():
        raise UsageError(f"--write-hardware {out}: is a directory")
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    mocks = None
    try:
        mocks = TwinMocks(cell, args.seed, effects, args.sim_speed)
        family = cell.robot_doc.get("controller")  # the robot config names its controller's family, if not a KR C2
        if family:
            robot = mocks.serve_family(str(family))
        else:
            eki, rsi = ("127.0.0.1", free_port()), ("127.0.0.1", free_port(socket.SOCK_DGRAM))
            mocks.serve_controller(eki, rsi, connect_timeout_s=CONTROLLER_CONNECT_S)
            robot = krc2_robot_doc(mocks, eki, rsi)
        doc = hardware_doc(mocks, robot)
        text = (f"# trackcal mock --cell {args.cell} --seed {args.seed}: the digital twin's cell on loopback "
                f"(pid {os.getpid()}); valid while it runs\n" + yaml.safe_dump(doc, sort_keys=False))  # fmt: skip
        if out is not None:
            write_text(out, text, InputError)
        table = Table(title=f"trackcal mock: cell {cell.name}, seed {args.seed}"
                            + (f", effects {effects}" if effects else ""))  # fmt: skip
        table.add_column("device")
        table.add_column("address")
        for name, where in mocks.addresses().items():
            table.add_row(name, where)
        console.print(table)
        console.print(f"hardware config: {out}" if out is not None else text, markup=False)
        console.print("serving; Ctrl-C (SIGINT) or SIGTERM stops")
        stop.wait()  # the SIGINT/SIGTERM handler sets it (lock waits are interruptible by signals on POSIX)
        served = "" if family else f" (the KR C2 mock connected {mocks.controllers_connected()} time(s))"
        console.print(f"stopping{served}")
    finally:
        if mocks is not None:
            mocks.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
