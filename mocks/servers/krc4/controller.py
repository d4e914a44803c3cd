"""Deterministic mock of a KUKA KR C4 / KR C5 running configs/krc4 (trackcal_eki.src with its RSI context).

The KR C2 mock (mocks/servers/kuka/controller.py: the program's requests, the motion, faults, braking, RSI
lateness) with what KSS 8 changes:

- EKI: the controller serves on `eki_addr` (port 0: a free one; `eki_addr` then says which) and trackcal
  connects (mocks/servers/krc4/links.py); when trackcal goes away the program clears and reopens its channel
  and the next client is served.
- RSI: UDP to `rsi_addr` every cycle (IPO_FAST 4 ms by default), from the start of the program (RSI_ON comes
  before the EKI loop in trackcal_eki.src), with or without an EKI client: a client that speaks only RSI (the
  judge written to kuka_rsi_hw_interface's rules) gets the stream too.
- Axis corrections (RSI_ON(#ABSOLUTE), AXISCORR fed by AK.A1..AK.A6, HOLDON 1): the AK values of the last answer
  received in time are the offsets of every axis from where the program put it, applied from the next cycle on;
  the joints reported (AIPos, EKI's $AXIS_ACT_MEAS, the twin's robot) are the PTP's plus the correction. This is
  how kuka_rsi_hw_interface moves a robot (src/kuka_hardware_interface.cpp: correction = command - the ASPos
  of the first frame).
- Stop (the BOOL Stop of trackcal_rsi_ethernet.xml, trackcal's motion guard): an answer whose <Stop> rises from 0
  to 1 during a move brakes it from the next cycle on, as interrupt 18 of trackcal_eki.src does (BRAKE, the move
  answered with Error 6 at standstill); `rsi_stops` records the number of the frame (1 = the first sent) whose
  answer raised it, for every rising edge.
- Lateness: more than max_late_packages late answers in a row stop the robot, as the ETHERNET object's Timeout
  parameter does (100 by default: kuka_rsi_hw_interface/krl/KR_C4_RSI_4+/README.md). Late answers are counted
  only while an EKI client is connected (the mock does not stop the robot because nobody has started trackcal
  yet, nor when a judge speaks RSI alone), and a new EKI client starts from a clean RSI state (the operator
  restarted the program after an RSI stop).
"""

from __future__ import annotations

from collections.abc import Sequence

from trackcal.drivers.krc4.configs import RSI
from trackcal.drivers.kuka.eki_codec import ERR_RSI_STOPPED
from trackcal.mocks.servers.krc4.links import EkiServerEnd, RsiUdpEnd
from trackcal.mocks.servers.kuka.controller import MockKrc2

KRC4_CYCLE_S = 0.004  # IPO_FAST (drivers.krc4.client.KRC4_CYCLE_S)
ETHERNET_TIMEOUT = 100  # the ETHERNET object's Timeout: late packets before RSI stops (KR_C4_RSI_4+/README.md)


class MockKrc4(MockKrc2):
    def __init__(
        self,
        eki_addr: tuple[str, int],
        rsi_addr: tuple[str, int],
        clock,
        initial_joints_deg: Sequence[float],
        *,
        cycle_s: float = KRC4_CYCLE_S,
        rsi_passive: bool = RSI.passive,
        max_late_packages: int = ETHERNET_TIMEOUT,
        **options,
    ) -> None:
        super().__init__(
            eki_addr,
            rsi_addr,
            clock,
            initial_joints_deg,
            rsi_protocol="udp",
            rsi_passive=rsi_passive,
            cycle_s=cycle_s,
            max_late_packages=max_late_packages,
            **options,
        )
        self._eki = EkiServerEnd(eki_addr, self.errors)
        self.eki_addr = self._eki.addr
        self._rsi = RsiUdpEnd(rsi_addr, "udp", self.sen_type, self.errors, self._rsi_lost)
        self.correction_deg: tuple[float, ...] = (0.0,) * 6
        self.rsi_stops: list[int] = []  # the frame whose answer raised Stop, per rising edge
        self._stop_high = False

    @property
    def joints_deg(self) -> tuple[float, ...]:
        return tuple(round(q + c, 4) for q, c in zip(self.motion.joints_deg, self.correction_deg, strict=True))

    def stop(self) -> None:
        super().stop()
        self._eki.shut()

    def _connect_first(self) -> bool:
        self._rsi.open_udp()  # RSI_ON before the EKI loop: the stream runs from the start
        return True

    def _reconnect(self) -> OSError | None:
        was = self._eki.connected
        failure = super()._reconnect()
        if not was and self._eki.connected:  # a new client: the program was started afresh
            self.consecutive_late = 0
            if self.rsi_stopped:
                self.rsi_stopped, self._fault = False, 0 if self._fault == ERR_RSI_STOPPED else self._fault
                self._rsi.open_udp()
        return failure

    def _rsi_exchange(self) -> None:
        late, consecutive = self.late_packets, self.consecutive_late
        before = self._rsi.answer
        super()._rsi_exchange()
        answer = self._rsi.answer
        if answer is not before and answer is not None:
            self.correction_deg = tuple(float(v) for v in answer.corrections)
            if answer.stop and not self._stop_high:  # a rising edge: the STOP wired to interrupt 18 brakes
                self.rsi_stops.append(self.frames_sent)
                if self.motion.mode == "moving":
                    self.motion.brake()
            self._stop_high = answer.stop
        elif not self._eki.connected:  # nobody to be late for: not counted
            self.late_packets, self.consecutive_late = late, consecutive
