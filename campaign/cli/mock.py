"""`trackcal mock`: the digital twin's cell as a stand-alone set of devices, for `trackcal run --hardware`.

    trackcal mock --cell kr270 --seed 3 --write-hardware cell.yaml --detach
    trackcal run --cell kr270 --plan plan.json --hardware cell.yaml --session sessions/a
    trackcal mock --stop cell.yaml

`--detach` starts the mock in a process of its own and returns only once every server listens and the hardware
file is written (the child says so on a pipe after writing it), so the next command finds the cell; a mock run
with `&` instead races the shell's next command. `--stop FILE` stops the mock whose pid the file names.

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
import re
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import yaml
from rich.table import Table

from trackcal.calib.io.files import write_text
from trackcal.calib.model.cell import load_cell
from trackcal.campaign.cells.checks import names_told_apart
from trackcal.campaign.cells.sim import CONTROLLER_CONNECT_S, TwinMocks, free_port, hardware_doc, krc2_robot_doc
from trackcal.campaign.cli.console import console, print_table
from trackcal.campaign.errors import InputError, UsageError
from trackcal.campaign.jobs.simulate import parse_effects

# --detach: how long the child may take to import, load the cell and open its servers (a few seconds; a
# loaded 2-core machine has taken 20), and how long --stop waits for the mock to close them
READY_TIMEOUT_S = 120.0
STOP_TIMEOUT_S = 30.0
PID_LINE = re.compile(r"^# trackcal mock .*\(pid (\d+)\)")


def cmd_mock(args) -> int:
    if args.stop is not None:
        if args.cell or args.detach or args.write_hardware:
            raise UsageError("--stop FILE takes no other option: it stops the mock that wrote FILE")
        return stop_mock(Path(args.stop))
    if not args.cell:
        raise UsageError("--cell is required (or --stop FILE)")
    effects = parse_effects(args.effect)
    if args.sim_speed is not None and not args.sim_speed > 0:
        raise UsageError("--sim-speed must be positive (simulated seconds per real second)")
    out = Path(args.write_hardware) if args.write_hardware else None
    if out is not None and out.is_dir():
        raise UsageError(f"--write-hardware {out}: is a directory")
    if args.detach:
        if out is None:
            raise UsageError("--detach needs --write-hardware FILE: the hardware config is how run finds the mock")
        return detach(args, out)
    cell = load_cell(args.cell)
    names_told_apart(cell)  # its simulated operator reads the cell display
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
        text = (
            f"# trackcal mock --cell {args.cell} --seed {args.seed}: the digital twin's cell on loopback "
            f"(pid {os.getpid()}); valid while it runs\n" + yaml.safe_dump(doc, sort_keys=False)
        )
        if out is not None:
            write_text(out, text, InputError)
        table = Table(
            title=f"trackcal mock: cell {cell.name}, seed {args.seed}" + (f", effects {effects}" if effects else "")
        )
        table.add_column("device")
        table.add_column("address")
        for name, where in mocks.addresses().items():
            table.add_row(name, where)
        print_table(table)
        console.print(f"hardware config: {out}" if out is not None else text, markup=False)
        console.print("serving; Ctrl-C (SIGINT) or SIGTERM stops")
        if args.ready_fd is not None:  # --detach's parent waits for this line: every server listens, file written
            with os.fdopen(args.ready_fd, "w") as ready:
                ready.write(f"ready {os.getpid()}\n")
        stop.wait()  # the SIGINT/SIGTERM handler sets it (lock waits are interruptible by signals on POSIX)
        served = "" if family else f" (the KR C2 mock connected {mocks.controllers_connected()} time(s))"
        console.print(f"stopping{served}")
    finally:
        if mocks is not None:
            mocks.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0


def detach(args, out: Path) -> int:
    """The mock in a process of its own (its own session: the terminal's Ctrl-C and hang-up do not reach it),
    its output in FILE.log; returns once the child has written the hardware file, or says why it did not."""
    log_path = out.with_name(out.name + ".log")
    argv = [
        sys.executable,
        "-m",
        "trackcal.campaign.cli",
        "mock",
        "--cell",
        args.cell,
        "--seed",
        str(args.seed),
        "--write-hardware",
        str(out),
    ]
    for effect in args.effect or []:
        argv += ["--effect", effect]
    if args.sim_speed is not None:
        argv += ["--sim-speed", repr(args.sim_speed)]
    read_end, write_end = os.pipe()
    try:
        with open(log_path, "wb") as log:
            child = subprocess.Popen(
                [*argv, "--ready-fd", str(write_end)],
                pass_fds=(write_end,),
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
    except OSError as exc:
        os.close(read_end)
        raise InputError(f"{log_path}: cannot start the mock ({exc.strerror or exc})") from None
    finally:
        os.close(write_end)
    with os.fdopen(read_end, "rb") as ready:
        answered, _, _ = select.select([ready], [], [], READY_TIMEOUT_S)
        line = ready.readline().decode("ascii", "replace") if answered else ""
    if line.startswith("ready"):
        console.print(
            f"trackcal mock serving in the background (pid {child.pid}), hardware config {out}, its output "
            f"in {log_path}; stop it with: trackcal mock --stop {out}",
            markup=False,
        )
        return 0
    if not answered:  # no word within the time: it will not come
        child.terminate()
        child.wait()
        raise InputError(f"the mock did not start within {READY_TIMEOUT_S:.0f} s (its output: {log_path})")
    child.wait()  # the pipe closed without a word: the child is exiting
    lines = [x for x in log_path.read_text(encoding="utf-8", errors="replace").splitlines() if x.strip()]
    why = lines[-1].removeprefix("error: ") if lines else f"exit code {child.returncode}"
    raise InputError(f"the mock did not start: {why}")


def mock_pid(path: Path) -> int:
    """The pid the hardware file of a mock names (its first line, written by cmd_mock)."""
    try:
        first = path.read_text(encoding="utf-8").partition("\n")[0]
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read ({getattr(exc, 'strerror', None) or exc})") from None
    m = PID_LINE.match(first)
    if m is None:
        raise InputError(f"{path}: not a hardware file written by trackcal mock (no '(pid N)' on its first line)")
    return int(m.group(1))


def running_mock(pid: int) -> bool:
    """A live `trackcal mock` process of that pid (a zombie or another program that reuses the pid is not)."""
    proc = Path(f"/proc/{pid}")
    if proc.is_dir():  # Linux: check what the pid is, not only that it exists
        try:
            state = (proc / "stat").read_text().rpartition(")")[2].split()[0]
            cmdline = (proc / "cmdline").read_bytes().split(b"\0")
        except OSError:
            return False
        return state != "Z" and b"mock" in cmdline and any(b"trackcal" in part for part in cmdline)
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def stop_mock(path: Path) -> int:
    """SIGTERM to the mock that wrote `path`, then wait until it has closed its servers and exited."""
    pid = mock_pid(path)
    if not running_mock(pid):
        raise InputError(f"{path}: no trackcal mock runs with pid {pid} (already stopped)")
    try:
        os.kill(pid, signal.SIGTERM)
    except ProcessLookupError:
        raise InputError(f"{path}: no trackcal mock runs with pid {pid} (already stopped)") from None
    deadline = time.monotonic() + STOP_TIMEOUT_S
    while running_mock(pid):
        if time.monotonic() > deadline:
            raise InputError(f"{path}: the mock (pid {pid}) did not stop within {STOP_TIMEOUT_S:.0f} s of SIGTERM")
        time.sleep(0.05)
    console.print(f"trackcal mock stopped (pid {pid})")
    return 0
