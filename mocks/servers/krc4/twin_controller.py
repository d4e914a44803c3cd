"""The mock KR C4 as the twin's robot for `trackcal mock` (mocks/controllers.py): the controller thread of
MockKrc4 in the mock's process (its own process, apart from `trackcal run`), on the world's clock, with the robot
at the world's joints; it serves EKI on a free loopback port and streams RSI to another free port, where trackcal
will listen (both written into the hardware file). The world's robot is put where the controller reports it at
every cycle (on_joints), in degrees rounded to the 4 decimals the campaign stores, as the KR C2 mock of `run --sim`
does, so a measurement's noise identity is the same at the same pose."""

from __future__ import annotations

import socket

import numpy as np

from trackcal.mocks.servers.krc4.controller import KRC4_CYCLE_S, MockKrc4

CONTROLLER = "krc4"
CONNECT_S = 24 * 3600.0  # the controller waits this long for trackcal's first connection
# The mock's axis speed: the KR C2 twin's of `run --sim` (campaign/cells/sim.py SIM_JOINT_SPEED_DEG_S, the KR QUANTEC's
# slowest main axis); the joints reached are the targets either way (no overshoot).
JOINT_SPEED_DEG_S = 96.0


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A UDP port nobody uses now (trackcal binds it later with SO_REUSEADDR)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


class TwinKrc4:
    def __init__(self, world, seed: int, speed: float | None = None) -> None:
        self.world = world
        limits = np.degrees(world.twin.cell.chain.limits_array())
        self.rsi_addr = ("127.0.0.1", free_udp_port())
        self.controller = MockKrc4(
            ("127.0.0.1", 0),
            self.rsi_addr,
            world.clock,
            tuple(world.q_deg),
            on_joints=world.robot_at,
            joint_speed_deg_s=JOINT_SPEED_DEG_S,
            seed=seed,
            overshoot_deg=0.0,
            connect_timeout_s=CONNECT_S,
            soft_limits_deg=[(float(lo), float(hi)) for lo, hi in limits],
        ).start()

    def hardware(self) -> dict:
        """The robot section of the hardware file (campaign/cells/hardware.py, drivers/krc4/family.py)."""
        host, port = self.controller.eki_addr
        return {
            "protocol": CONTROLLER,
            "controller_host": host,
            "eki": {"port": port},
            "rsi": {
                "host": self.rsi_addr[0],
                "port": self.rsi_addr[1],
                "passive": self.controller.rsi_passive,
                "cycle_s": KRC4_CYCLE_S,
            },
            "connect_timeout_s": 30.0,
        }

    def addresses(self) -> dict[str, str]:
        host, port = self.controller.eki_addr
        return {"KR C4 serves EKI": f"{host}:{port}", "KR C4 sends RSI to": "udp {}:{}".format(*self.rsi_addr)}

    def stop(self) -> None:
        self.controller.stop()


def serve(world, seed: int, speed: float | None = None) -> TwinKrc4:
    return TwinKrc4(world, seed, speed)
