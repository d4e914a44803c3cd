"""The simulated operator of `--sim`: reads the request shown to him, does it in the world, closes the door
and presses the acknowledge button of the (mock) cell PLC, exactly as a person at the cell would."""

from __future__ import annotations

import threading
import time

from .plc_server import MockPlc
from .world import World


class SimHuman:
    def __init__(self, world: World, plc: MockPlc, hold_s: float = 0.05, action_s: float = 60.0):
        self.world, self.plc, self.hold_s, self.action_s = world, plc, hold_s, action_s
        self.request: tuple[str, str] | None = None
        self.log: list[tuple[str, str, str]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sim-operator", daemon=True)

    def show(self, kind: str, target: str, text: str) -> None:
        """What the operator reads on the console when the request lamp lights."""
        self.log.append((kind, target, text))
        self.request = (kind, target)

    def start(self) -> SimHuman:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)

    def _run(self) -> None:
        while not self._stop.is_set():
            if self.plc.lamp and self.request is not None:
                kind, target = self.request
                self.request = None
                self.plc.open_door()  # he walks into the cell
                if kind == "change_station":
                    self.world.station = target
                elif kind == "move_reflector":
                    self.world.point = target
                self.world.clock.sleep(self.action_s)
                self.plc.close_door()  # and out again
                self.plc.press_acknowledge()
                time.sleep(self.hold_s)
                self.plc.release_acknowledge()
            time.sleep(0.002)
