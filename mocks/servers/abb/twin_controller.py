"""The mock ABB controller as the twin's robot for `trackcal mock` (mocks/controllers.py): the controller process
(process.MockAbbProcess) on free loopback ports, and a follower on its control port (`follow`: the joints at every
4 ms tick) that puts the twin's robot where the controller says it is, so the tracker mock measures the arm there.
The controller streams EGM to a free UDP port of this machine, which the hardware file names as trackcal's. The
controller runs `speed` times faster than the wall clock (`trackcal mock --sim-speed`; default 1), at most
MAX_SPEED."""

from __future__ import annotations

import contextlib
import socket
import threading

from trackcal.mocks.servers.abb.process import MockAbbProcess

CONTROLLER = "abb"
MAX_SPEED = 100.0  # the bound of the mock's --speed


class JointFollower:
    """Reads the control port's `follow` lines and hands each joint reading (deg) to on_joints."""

    def __init__(self, address: tuple[str, int], on_joints) -> None:
        self.address, self.on_joints = address, on_joints
        self.frames = 0
        self.q_deg: tuple[float, ...] | None = None
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._sock: socket.socket | None = None
        self._thread = threading.Thread(target=self._run, name="abb-joint-follower", daemon=True)

    def start(self) -> JointFollower:
        self._thread.start()
        return self

    def fresh(self, timeout_s: float = 2.0) -> bool:
        """Wait for a reading sent after this call."""
        with self._cond:
            seen = self.frames
            return self._cond.wait_for(lambda: self.frames > seen, timeout=timeout_s)

    def _run(self) -> None:
        while not self._stop.is_set():
            with contextlib.suppress(OSError, ValueError):
                self._follow()
            self._stop.wait(0.05)

    def _follow(self) -> None:
        with socket.create_connection(self.address, timeout=2.0) as s:
            self._sock = s
            s.sendall(b"follow\n")
            buf = b""
            while not self._stop.is_set():
                try:
                    data = s.recv(65536)
                except TimeoutError:
                    continue
                if not data:
                    return
                *lines, buf = (buf + data).split(b"\n")
                if lines:
                    q = tuple(float(v) for v in lines[-1].decode().split(","))
                    self.on_joints(q)
                    with self._cond:
                        self.q_deg, self.frames = q, self.frames + 1
                        self._cond.notify_all()

    def stop(self) -> None:
        self._stop.set()
        if self._sock is not None:
            with contextlib.suppress(OSError):
                self._sock.shutdown(socket.SHUT_RDWR)
        self._thread.join(timeout=5.0)


class TwinAbb:
    def __init__(self, world, seed: int, speed: float | None = None) -> None:
        q0 = ",".join(f"{v:.4f}" for v in world.q_deg)
        rate = f"{min(speed or 1.0, MAX_SPEED):g}"
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:  # the port trackcal will listen on for EGM
            s.bind(("127.0.0.1", 0))
            self.egm_port = s.getsockname()[1]
        robot = world.twin.cell.chain.name  # the cell's arm (irb120, irb6700): its flange for the robtarget
        self.process = MockAbbProcess(
            seed=seed, args=["--q0-deg", q0, "--speed", rate, "--robot", robot, "--egm", f"127.0.0.1:{self.egm_port}"]
        ).start()
        try:
            self.follower = JointFollower(("127.0.0.1", self.process.control_port), world.robot_at).start()
        except BaseException:
            self.process.stop()
            raise

    def hardware(self) -> dict:
        """The robot section of the hardware file (campaign/cells/hardware.py, drivers/abb/family.py)."""
        host, port = self.process.address
        return {
            "protocol": CONTROLLER,
            "host": host,
            "port": port,
            "connect_timeout_s": 30.0,
            "egm": {"host": "127.0.0.1", "port": self.egm_port},
        }

    def addresses(self) -> dict[str, str]:
        host, port = self.process.address
        return {
            "ABB controller (Robot Web Services)": f"{host}:{port}",
            "its control port (the mock's own)": f"{host}:{self.process.control_port}",
        }

    def stop(self) -> None:
        self.follower.stop()
        self.process.stop()


def serve(world, seed: int, speed: float | None = None) -> TwinAbb:
    return TwinAbb(world, seed, speed)
