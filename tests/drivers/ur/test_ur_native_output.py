"""ur_rtde's own console lines (its C++ threads write them to fds 2 and 1 whatever its `verbose` flag says) go to a
log, the session's robot-native.log in a campaign, so that trackcal's one line stands alone on the console
(drivers/ur/client.py divert_native_output). Each check runs in a process of its own: the diversion moves the
process's file descriptors."""

import subprocess
import sys

from trackcal.drivers.ur.client import divert_native_output

HOST = "127.0.0.99"

# The programs each check runs in a child process of its own (the diversion moves the process's file descriptors).
DIVERT_AND_WRITE = """
import os, sys
from trackcal.drivers.ur.client import divert_native_output
print("before", flush=True)
assert divert_native_output("native.log") and divert_native_output("other.log")  # once per process
os.write(2, b"native on fd 2\\n")  # what std::cerr does
os.write(1, b"native on fd 1\\n")  # what std::cout does
print("ours on stderr", file=sys.stderr)
print("ours on stdout")
"""
DROPPED_LINK = """
import sys, time
import rtde_receive
from trackcal.drivers.ur.client import divert_native_output
from trackcal.mocks.servers.ur.process import MockUrProcess
divert_native_output("native.log")
with MockUrProcess("HOST", seed=1) as ur:
    r = rtde_receive.RTDEReceiveInterface("HOST")
    r.getActualQ()
    ur.inject("drop")
    deadline = time.monotonic() + 20
    while r.isConnected() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.2)
print("trackcal's one line", file=sys.stderr)
"""


def run_python(code: str, tmp_path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path)


def test_native_writes_go_to_the_log_and_python_keeps_the_console(tmp_path):
    out = run_python(DIVERT_AND_WRITE, tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stderr == "ours on stderr\n" and out.stdout == "before\nours on stdout\n"
    assert (tmp_path / "native.log").read_text() == "native on fd 2\nnative on fd 1\n"
    assert not (tmp_path / "other.log").exists()


def test_the_lines_ur_rtde_prints_on_a_dropped_link_reach_the_log_only(tmp_path):
    """The unmodified ur_rtde client against the mock, whose connection is dropped (its control port): the receive
    thread's "RTDEReceiveInterface boost system Exception" line lands in the log, the console has ours only."""
    out = run_python(DROPPED_LINK.replace("HOST", HOST), tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stderr == "trackcal's one line\n"
    assert "RTDEReceiveInterface" in (tmp_path / "native.log").read_text()


def test_not_diverted_under_a_capturing_runner(capsys):
    """pytest's capture replaces sys.stderr: the descriptors are not the console's, nothing moves."""
    assert divert_native_output("/nonexistent/never-written.log") is False
