"""The mock UR controller as the twin's robot for `trackcal mock` (mocks/controllers.py): the controller process
(process.MockUrProcess) on a loopback address of its own (the UR ports are fixed: 29999, 30001-30004), and the
follower (follow.JointFollower) that puts the twin's robot where the controller reports it, at every frame. Joint
angles reach the world in degrees; the world rounds them to the 4 decimals the campaign stores, so a measurement's
noise identity is that of `run --sim` at the same pose. The controller runs `speed` times faster than the wall
clock (`trackcal mock --sim-speed`; default 1, real time: a third-party client driving `trackcal mock` sees a move
take the time a UR takes), at most MAX_SPEED (the bound of the mock controller's --speed).

Added by the driver side of issue 21 (branch h21-driver) to connect the mock to the twin's cell."""

from __future__ import annotations

import socket

from trackcal.mocks.servers.ur.follow import JointFollower
from trackcal.mocks.servers.ur.process import MockUrProcess
from trackcal.mocks.servers.ur.server import RTDE_PORT

CONTROLLER = "ur"
MAX_SPEED = 100.0  # controller seconds per wall second: the most python -m trackcal.mocks.servers.ur --speed takes
FIRST_HOST = 31  # 127.0.0.31 ... 127.0.0.254: the first address where nobody serves RTDE


def claim_loopback() -> tuple[str, socket.socket]:
    """A loopback address where no UR controller serves yet (nothing on the RTDE port), claimed: a UDP socket bound to
    the RTDE port number there, which the caller holds while its controller runs. A second claimer's bind fails
    (EADDRINUSE, no SO_REUSEADDR), so two processes that look at once (two xdist workers, two `trackcal mock`) cannot
    take the same address; TCP ports are a space of their own, so the claim does not stand in the controller's way."""
    for n in range(FIRST_HOST, 255):
        host = f"127.0.0.{n}"
        claim = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            claim.bind((host, RTDE_PORT))
        except OSError:  # claimed by another process
            claim.close()
            continue
        with socket.socket() as s:
            s.settimeout(0.2)
            if s.connect_ex((host, RTDE_PORT)) != 0:
                return host, claim
        claim.close()  # a controller nobody claimed (a test's, on an address it names) serves here
    raise OSError("no free loopback address 127.0.0.31-254 for a mock UR controller")


class TwinUr:
    def __init__(self, world, seed: int, speed: float | None = None) -> None:
        self.world = world
        self.host, self.claim = claim_loopback()
        q0 = ",".join(f"{v:.4f}" for v in world.q_deg)
        rate = f"{min(speed or 1.0, MAX_SPEED):g}"
        try:
            self.process = MockUrProcess(self.host, seed=seed, args=["--q0-deg", q0, "--speed", rate]).start()
        except BaseException:
            self.claim.close()
            raise
        self.follower = JointFollower(self.host, world.robot_at).start()

    def hardware(self) -> dict:
        """The robot section of the hardware file (campaign/cells/hardware.py, drivers/ur/family.py)."""
        # the mock's joint speeds are the UR10's (120 deg/s base and shoulder, 180 deg/s the others: mocks/servers/ur
        # motion.py, which caps any faster request); 179 deg/s at 100 % override is within what ur_rtde's moveJ takes
        # (MOVEJ_SPEED_MAX_DEG_S: 400 made every move at 100 %, an ISO 9283 test's, a ValueError), and the campaign's
        # 30 % moves at 54 deg/s; a loaded test machine may pause the mock a second or two
        return {
            "protocol": CONTROLLER,
            "host": self.host,
            "connect_timeout_s": 30.0,
            "joint_speed_deg_s": 179.0,
            "joint_acceleration_deg_s2": 400.0,
            "stale_s": 2.5,
        }

    def addresses(self) -> dict[str, str]:
        return {"UR controller (dashboard 29999, RTDE 30004, script 30003)": self.host}

    def stop(self) -> None:
        self.follower.stop()
        self.process.stop()
        self.claim.close()


def serve(world, seed: int, speed: float | None = None) -> TwinUr:
    return TwinUr(world, seed, speed)
