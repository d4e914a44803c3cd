"""The simulated operator of the twin's cell: reads the request trackcal shows on the HMI (the request registers
of the mock cell PLC), does it in the world, closes the door and presses the acknowledge button, exactly as a
person at the cell would. The PLC is the only channel, so the same operator serves a campaign in this process
(`trackcal run --sim`) and one in another process (`trackcal mock` + `trackcal run --hardware`)."""

from __future__ import annotations

import threading
import time

from trackcal.drivers.plc.codec import hmi_text
from trackcal.mocks.cell import World
from trackcal.mocks.servers.plc import MockPlc

# He looks at the HMI when trackcal writes its request lamp or registers (MockPlc.wait_request_written), and at least
# this often (wall seconds) besides; he looked every 2 ms before issue 41, a few hundred looks per second of a run.
LOOK_S = 0.05


class SimHuman:
    """He holds the acknowledge button until the request lamp goes out (at least `hold_s`, at most `max_hold_s`
    of wall time), so trackcal sees the press however slowly it polls. `action_s`: how long the action takes
    (world time). `acknowledges=False`: he does the work and closes the door but leaves the acknowledgement to
    someone else (the operator's page in `run --sim --operator web`); `acted` counts the requests he has done."""

    def __init__(
        self,
        world: World,
        plc: MockPlc,
        hold_s: float = 0.05,
        action_s: float = 60.0,
        max_hold_s: float = 30.0,
        acknowledges: bool = True,
    ):
        self.world, self.plc, self.hold_s, self.action_s = world, plc, hold_s, action_s
        self.acknowledges, self.acted = acknowledges, 0
        self.max_hold_s = max_hold_s
        self.log: list[tuple[str, str, str]] = []  # (kind, target, what the HMI showed), one per request done
        self.errors: list[str] = []
        self._seen: int | None = None  # sequence number of the last request done
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sim-operator", daemon=True)

    def start(self) -> SimHuman:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)

    def _run(self) -> None:
        written = -1  # the PLC's count of trackcal's writes to the request lamp and registers, as last looked at
        while not self._stop.is_set():
            try:
                request = self.plc.operator_request
            except ValueError as exc:  # a kind code he does not know: he waits for one he does
                if not self.errors or self.errors[-1] != str(exc):
                    self.errors.append(str(exc))
                request = None
            if request is not None and request.kind is not None and request.seq != self._seen and self.plc.lamp:
                self._seen = request.seq
                self._do(request.kind, request.target)
            written = self.plc.wait_request_written(written, LOOK_S)

    def _do(self, kind: str, target: str) -> None:
        self.log.append((kind, target, f"{kind.replace('_', ' ')} {target}".strip()))
        self.plc.open_door()  # he walks into the cell
        cell = self.world.twin.cell
        if kind == "change_station":
            self.world.station = _named(target, cell.stations)
        elif kind == "move_reflector":
            self.world.point = _named(target, cell.tool_points)
        self.world.clock.sleep(self.action_s)
        self.plc.close_door()  # and out again
        if not self.acknowledges:
            self.acted += 1
            return
        self.plc.press_acknowledge()
        time.sleep(self.hold_s)
        deadline = time.monotonic() + self.max_hold_s
        written = -1  # not looked yet: the first wait returns at once
        while self.plc.lamp and time.monotonic() < deadline and not self._stop.is_set():
            written = self.plc.wait_request_written(written, LOOK_S)
        self.plc.release_acknowledge()
        self.acted += 1


def _named(shown: str, names) -> str:
    """The name the HMI showed as `shown` (its first 16 ASCII characters: drivers.plc.codec.hmi_text), as a person
    reads the display and finds the nest or station so labelled; `shown` itself when none is (the world then says
    there is no such place)."""
    found = [name for name in names if hmi_text(name) == shown]
    return found[0] if len(found) == 1 else shown
