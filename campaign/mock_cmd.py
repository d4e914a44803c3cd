"""`trackcal mock`: the digital twin's cell as a stand-alone set of devices, for `trackcal run --hardware`.

    trackcal mock --cell kr270 --seed 3 --write-hardware cell.yaml &
    trackcal run --cell kr270 --plan plan.json --hardware cell.yaml --session sessions/a

The mocks of `run --sim` (campaign.devices.TwinMocks) on free loopback ports of this process: emScon tracker,
Modbus cell PLC with the simulated operator at its lamp (he reads the HMI request registers, the only channel
between the processes), serial meteo on a pseudo-terminal, and the KR C2, which like the real controller
connects to the EKI and RSI ports trackcal listens on (two free ports chosen here and written into the
hardware file), retrying until trackcal is there and starting afresh whenever trackcal goes away, so several
`run` / `resume` in a row each find a controller. Serves until SIGINT or SIGTERM, then exits 0.

Unlike `run --sim`, the twin does not know the session: the n-th measurement of a (station, point, pose)
counts from this mock's start, so a resumed campaign's noise is not that of an uninterrupted one.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import tempfile
import threading
from pathlib import Path

import yaml
from rich.table import Table

from calib.cell import load_cell

from .console import console
from .devices import TwinMocks
from .jobs import UsageError, parse_effects

# How often trackcal reads the acknowledge button (written into the hardware file); the simulated operator holds
# it until the request lamp goes out, as a person would, so no press is missed at any poll period.
POLL_S = 0.05
# The controller retries its connection this long before giving up (and the supervisor starts a fresh one).
CONTROLLER_CONNECT_S = 24 * 3600.0


def free_port(kind: int = socket.SOCK_STREAM, host: str = "127.0.0.1") -> int:
    """A port nobody listens on now (the OS picks it); trackcal binds it later with SO_REUSEADDR."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def hardware_doc(mocks: TwinMocks, eki: tuple[str, int], rsi: tuple[str, int]) -> dict:
    """The hardware config (campaign/hardware.py schema) of the running mocks."""
    thost, tport = mocks.tracker_mock.address
    phost, pport = mocks.plc.address
    return {
        "tracker": {"protocol": "emscon", "host": thost, "port": tport, "timeout_s": 10.0},
        "robot": {"protocol": "krc2", "eki": {"host": eki[0], "port": eki[1]},
                  "rsi": {"protocol": "tcp", "host": rsi[0], "port": rsi[1]}, "connect_timeout_s": 30.0},
        "plc": {"protocol": "modbus", "host": phost, "port": pport, "unit_id": mocks.plc.unit_id, "timeout_s": 2.0,
                "poll_s": POLL_S},
        "meteo": {"protocol": "serial", "port": mocks.meteo_mock.port_path, "baudrate": 9600, "timeout_s": 2.0},
    }  # fmt: skip


def write_atomically(path: Path, text: str) -> None:
    """Whoever waits for the file never reads half of it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


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
        eki, rsi = ("127.0.0.1", free_port()), ("127.0.0.1", free_port())
        mocks.serve_controller(eki, rsi, connect_timeout_s=CONTROLLER_CONNECT_S, restart=True)
        doc = hardware_doc(mocks, eki, rsi)
        text = (f"# trackcal mock --cell {args.cell} --seed {args.seed}: the digital twin's cell on loopback "
                f"(pid {os.getpid()}); valid while it runs\n" + yaml.safe_dump(doc, sort_keys=False))  # fmt: skip
        if out is not None:
            try:
                write_atomically(out, text)
            except OSError as exc:
                raise UsageError(f"--write-hardware {out}: cannot write ({exc.strerror})") from None
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
        console.print(f"stopping (the KR C2 mock connected {mocks.controllers_connected()} time(s))")
    finally:
        if mocks is not None:
            mocks.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0


def register_mock(sub) -> None:
    p = sub.add_parser("mock", help="serve the digital twin's cell on loopback for `trackcal run --hardware`")
    p.add_argument("--cell", required=True)
    p.add_argument("--seed", type=int, default=1, help="the twin's seed")
    p.add_argument("--effect", action="append", help="hidden effect NAME[:MAGNITUDE_MM] (repeatable)")
    p.add_argument("--write-hardware", metavar="FILE", help="write the hardware config of the mocks here")
    p.add_argument("--sim-speed", type=float, help="simulated seconds per real second (default: flat out)")
    p.set_defaults(func=cmd_mock)
