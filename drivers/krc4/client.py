"""KUKA KR C4 / KR C5 client (drivers.interfaces.Robot): the KR C2's (drivers.kuka.client.KukaKrc2: moves, stops,
resets, the motion guard, settling on RSI frames, the two channels cross-checked) with what KSS 8 changes:

- EKI: the controller serves, trackcal connects (drivers.krc4.eki_link, configs/krc4/TrackcalEki.xml);
- RSI: UDP only (the ETHERNET object of RSI 4.x/5.x; configs/krc4/trackcal_rsi_ethernet.xml has no PROTOCOL),
  answered by default (ONLYSEND FALSE: zero AK corrections with the frame's IPOC), every IPO_FAST cycle of 4 ms
  (or 12 ms: the hardware file says which, rsi.cycle_s). No empty-IPOC opener as the KR C2 sends: the RSI link
  follows the controller's address from its first frame (drivers.kuka.rsi_link).
- The motion guard, answered: drivers.krc4.cycle_guard reads it once per RSI frame while a move or a settle runs
  and, during a move, puts <Stop>1</Stop> in the answer to the next frame (the controller brakes in its next
  cycle); the EKI stop request still goes, and ends the move with the guard's code. A passive stream (ONLYSEND
  TRUE) carries no answer: the KR C2's guard (GUARD_S) then.
- The claim (one campaign per arm): the RSI port is a UDP port, which Linux lets a second socket bind too
  (SO_REUSEADDR), so `listen()` also holds a TCP listener on the same port number; a second campaign on this PC
  cannot bind it (ConnectionLost naming the port), and the kernel releases it when the process ends, even on kill -9.
"""

from __future__ import annotations

import contextlib
import socket

from trackcal.drivers.krc4.configs import EKI, RSI
from trackcal.drivers.krc4.cycle_guard import CycleGuard
from trackcal.drivers.krc4.eki_link import EkiClientLink
from trackcal.drivers.kuka.client import KukaKrc2
from trackcal.drivers.kuka.eki_codec import ERR_STOPPED
from trackcal.drivers.kuka.eki_codec import RobotState as EkiState
from trackcal.drivers.kuka.peers import bind

# IPO_FAST: "The RSI interface operates at 250 Hz (4ms cycle)" (kuka_rsi_hw_interface/krl/KR_C4_RSI_4+/README.md)
KRC4_CYCLE_S = 0.004
TITLE = "KR C4"


class KukaKrc4(KukaKrc2):
    """A KR C4 / KR C5 with configs/krc4's trackcal_eki program and its RSI context running."""

    def __init__(
        self,
        eki_port: int,
        rsi_host: str,
        rsi_port: int,
        *,
        controller_host: str,
        rsi_passive: bool = RSI.passive,
        rsi_cycle_s: float = KRC4_CYCLE_S,
        **options,
    ) -> None:
        super().__init__(
            controller_host,
            eki_port,
            rsi_host,
            rsi_port,
            "udp",
            controller_host=controller_host,
            rsi_passive=rsi_passive,
            rsi_cycle_s=rsi_cycle_s,
            **options,
        )
        mode = "passive" if rsi_passive else "answered"
        device = f"{TITLE} {controller_host} eki {eki_port} rsi udp {mode} {rsi_host}:{rsi_port}"
        self.device = self._peers.device = self.rsi.device = device
        self.eki = EkiClientLink(eki_port, self._peers, io_timeout_s=self.io_timeout_s)
        self._claim: socket.socket | None = None
        self.cycle_guard: CycleGuard | None = None
        if not rsi_passive:  # the guard's stop rides on the answers: the moving thread reads what it kept
            plc = self.motion_guard or (lambda: None)
            self.cycle_guard = CycleGuard(plc, self._asked, self._is_moving, self.rsi)
            self.motion_guard = self.cycle_guard.state

    def connect(self) -> None:
        if self.eki.connected:
            return
        super().connect()
        if self.cycle_guard is not None:
            self.cycle_guard.start()

    def move(self, target_deg: tuple[float, ...], speed_override_pct: float) -> None:
        with self._armed():
            super().move(target_deg, speed_override_pct)

    def wait_settled(self, tolerance_deg: float, window_s: float, timeout_s: float) -> tuple[float, ...]:
        with self._armed():
            return super().wait_settled(tolerance_deg, window_s, timeout_s)

    def _armed(self) -> contextlib.AbstractContextManager:
        return contextlib.nullcontext() if self.cycle_guard is None else self.cycle_guard.armed()

    def _asked(self) -> str | None:
        with self._motion:
            return self._stop_asked

    def _is_moving(self) -> bool:
        with self._motion:
            return self._moving is not None

    def _await_state(self, command_id: int, guarded: bool) -> tuple[EkiState, str | None]:
        """The KR C2's, and a move the controller braked on the RSI stop before the moving thread's own look at
        the guard ends with the reason that raised it (its code), not a bare Error 6."""
        state, stopped = super()._await_state(command_id, guarded)
        tripped = None if self.cycle_guard is None else self.cycle_guard.tripped
        if guarded and not stopped and tripped and state.error == ERR_STOPPED:
            stopped = tripped
        return state, stopped

    def listen(self) -> None:
        """Bind the RSI port and hold the arm's claim on it (see the module docstring). Idempotent."""
        super().listen()
        if self._claim is None:
            host, port = self.rsi.address
            self._claim = bind(socket.SOCK_STREAM, host, port, "the claim of this robot (RSI port, TCP)", self.device)

    def close(self) -> None:
        if self.cycle_guard is not None:
            self.cycle_guard.close()
        super().close()
        claim, self._claim = self._claim, None
        if claim is not None:
            with contextlib.suppress(OSError):
                claim.close()


DEFAULT_EKI_PORT = EKI.port
