"""State of the mock UR e-Series controller, stepped one 2 ms tick at a time, without sockets (server.py serves it).

What it keeps, with the public source of each rule:
- Robot, safety and runtime state as RTDE reports them (RTDE guide: robot_mode -1..8, safety_mode 1..13,
  runtime_state 0..5, robot_status_bits bit 0 power on / bit 1 program running, safety_status_bits bit 0 normal,
  bit 2 protective stopped, bit 4 safeguard stopped, bit 10 stopped due to safety).
- The registers (RTDE guide: input/output int and double registers 0..47, bit registers 64..127).
- ur_rtde's control script, recognised and emulated (it cannot be interpreted): ur_rtde 1.6.5 embeds
  scripts/rtde_control.script ("RTDE Control Script Loaded (14.02.2024-12:23)" in librtde.so.1.6.5). Its main
  loop, once per sync() (one tick): command id in input_int_register_0 (+ reg_offset_int, 24 with upper range
  registers); id 0 -> executing_cmd = False and signal_ready (output_int_register_0 = 1); realtime ids (servo,
  speed, force) -> process and signal_ready; any other id, once per command -> process_cmd, which blocks for a
  synchronous move and ends with signal_done_with_cmd (output_int_register_0 = 2) unless it was STOP_SCRIPT (255).
  movej (1): q in input_double_register_0..5, velocity 6, acceleration 7, async flag input_int_register_1 (movel
  (3) the same with a pose p[x, y, z, rx, ry, rz] and the tool's speed and acceleration: linear.py); an
  asynchronous move runs in a thread that writes the async progress register (output_int_register_2: bits 24-30
  operation id, 16-23 write count, bit 15 running; -1 written as finished). stopj (34) / stopl (33): deceleration
  in input_double_register_0, async flag in input_int_register_1 (exec_stopl_stopj: the stop runs in a thread that
  reports on the async progress register). protective_stop (31). Other ids are not emulated: the script ends with a
  runtime error text, as a failing real script would, so a client sees the program stop instead of a fake success.
  The script text ur_rtde sends (control port `script`) was read to check these: 1175 lines, the main loop above.
- Motion (motion.py, linear.py) at the 500 Hz tick; a stop's deceleration is in the running path's units (rad/s^2
  of the leading joint on a movej, m/s^2 of the tool on a movel: stopj and stopl alike); a protective or safeguard
  stop brakes the arm at `stop_decel` (a category 2 stop: decelerate on the path, then hold).
- A protective stop ends the running program (ur_rtde's documented recovery: unlockProtectiveStop through the
  dashboard, then reuploadScript). Unlocking is refused until 5 s after the stop (Dashboard Server e-Series manual:
  "Cannot unlock protective stop until 5s after occurrence...", `unlock_delay_s`). A safeguard stop pauses the
  program and its move; safeguard_reset resumes them (automatic reset).

Determinism: every value is a function of the seed and of the commands at their ticks (integer counts).
"""

from __future__ import annotations

import math
import random
import re
import threading
import time
from collections.abc import Callable, Sequence

from trackcal.mocks.servers.ur import rtde_codec as rc
from trackcal.mocks.servers.ur.kinematics import Calibration, factory_calibration, tcp_pose, tcp_speed
from trackcal.mocks.servers.ur.linear import LinearPath
from trackcal.mocks.servers.ur.motion import TICK_S, UR10_LIMITS_RAD, UR10_VMAX_RAD_S, Motion, Path, Profile

# RTDE guide enumerations
ROBOT_MODE = {
    -1: "NO_CONTROLLER",
    0: "DISCONNECTED",
    1: "CONFIRM_SAFETY",
    2: "BOOTING",
    3: "POWER_OFF",
    4: "POWER_ON",
    5: "IDLE",
    6: "BACKDRIVE",
    7: "RUNNING",
    8: "UPDATING_FIRMWARE",
}
RUNNING, IDLE, POWER_OFF, POWER_ON = 7, 5, 3, 4
SAFETY_MODE = {
    1: "NORMAL",
    2: "REDUCED",
    3: "PROTECTIVE_STOP",
    4: "RECOVERY",
    5: "SAFEGUARD_STOP",
    6: "SYSTEM_EMERGENCY_STOP",
    7: "ROBOT_EMERGENCY_STOP",
    8: "VIOLATION",
    9: "FAULT",
    10: "VALIDATE_JOINT_ID",
    11: "UNDEFINED_SAFETY_MODE",
    12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
    13: "SYSTEM_THREE_POSITION_ENABLING_STOP",
}
NORMAL, PROTECTIVE_STOP, SAFEGUARD_STOP = 1, 3, 5
STOPPING, STOPPED, PLAYING, PAUSING, PAUSED, RESUMING = 0, 1, 2, 3, 4, 5
JOINT_RUNNING_MODE = 253  # RTDE guide joint_mode
SAFETY_BITS = {NORMAL: 1 << 0, PROTECTIVE_STOP: (1 << 2) | (1 << 10), SAFEGUARD_STOP: (1 << 4) | (1 << 10)}

# ur_rtde RTDE::RobotCommand::Type ids emulated (scripts/rtde_control.script process_cmd)
MOVEJ, MOVEL, PROTECTIVE_STOP_CMD, STOPL, STOPJ, STOP_SCRIPT = 1, 3, 31, 33, 34, 255
SET_PAYLOAD, SET_TCP, SET_WATCHDOG, IS_JOINTS_WITHIN_LIMITS, GET_TCP_OFFSET = 17, 29, 35, 37, 40
GET_FK_DEFAULT, GET_FK_ARGS, IS_STEADY = 43, 44, 47
# realtime ids of the 1.6.5 main loop ("if cmd == 24 or cmd == 11 or ...": processed every cycle)
REALTIME_CMDS = frozenset({24, 11, 9, 10, 6, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71})

HOME_RAD = (0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0)
# protective / safeguard stop deceleration of the leading joint (rad/s^2): a category 2 stop; UR publishes stopping
# distances per joint, not a rate, so this is the mock's choice (ur_rtde's stopJ default is 2.0, the maximum 40).
STOP_DECEL = 10.0

_SCRIPT_ID = re.compile(r"^def rtde_control\(\):", re.M)
# ur_rtde 1.6.5 writes the offset after the template line's comment, at the start of the next line
# ("global reg_offset_int = # int register offset\n24    global ..."): URScript reads the assignment on
_REG_OFFSET = re.compile(r"global reg_offset_(int|float)\s*=\s*(?:#[^\n]*)?\s*(\d+)")
_PROGRAM = re.compile(r"^(?:def|sec)\s+(\w+)\s*\(\s*\)\s*:", re.M)


class UrController:
    def __init__(
        self,
        seed: int = 0,
        q0: Sequence[float] = HOME_RAD,
        version: tuple[int, int, int, int] = (5, 11, 1, 108318),
        model: str = "UR10",
        unlock_delay_s: float = 5.0,
        remote_control: bool = True,
        vmax: Sequence[float] = UR10_VMAX_RAD_S,
        limits=UR10_LIMITS_RAD,
        stop_decel: float = STOP_DECEL,
        protective_stop_on_move: int = 0,
        powered: bool = True,
    ) -> None:
        if len(q0) != 6:
            raise ValueError("q0 needs 6 joint values")
        self.lock = threading.RLock()
        self.seed = seed
        rng = random.Random(f"ur-controller/{seed}")
        self.version = tuple(int(v) for v in version)
        self.model = model
        self.serial = f"2021{rng.randrange(10**6, 10**7)}"
        self.calibration: Calibration = factory_calibration(seed)
        self.boot_s = round(rng.uniform(100.0, 10000.0), 3)  # controller uptime at tick 0 (timestamp)
        self.temperatures = tuple(round(30.0 + rng.uniform(0.0, 5.0), 2) for _ in range(6))
        self.unlock_delay_s = float(unlock_delay_s)
        self.remote_control = bool(remote_control)
        self.limits = tuple((float(lo), float(hi)) for lo, hi in limits)
        self.stop_decel = float(stop_decel)
        self.protective_stop_on_move = int(protective_stop_on_move)
        self.motion = Motion(q0, vmax)
        self.tick = 0
        self.robot_mode = RUNNING if powered else POWER_OFF
        self.safety_mode = NORMAL
        self.runtime_state = STOPPED
        self.program: str | None = None  # name of the running / last program
        self.loaded_program: str | None = None
        self.in_int = [0] * 48
        self.in_double = [0.0] * 48
        self.in_bits = 0  # input bit registers 0..127 as one integer
        self.out_int = [0] * 48
        self.out_double = [0.0] * 48
        self.out_bits = 0
        self.inputs: dict[str, object] = {}  # other RTDE inputs (speed slider, outputs masks ...)
        self.tcp = (0.0, 0.0, 0.0)
        self.payload = 0.0
        self.watchdog_set = False  # the script asked for an RTDE watchdog (recorded; the mock never trips it)
        self.messages: list[tuple[int, str, int]] = []  # text messages for RTDE clients (number, text, level)
        self.message_count = 0
        self.log: list[str] = []  # controller log (for tests and people)
        self.scripts: list[str] = []  # names of the programs received
        self.last_script = ""  # text of the last program received (control port: `script`)
        self.commands: list[int] = []  # control script command ids processed
        # when each was taken, CLOCK_MONOTONIC (one clock for every process of the machine, clock_gettime(2)): the
        # door-to-stop latency of bench/bench_ur_mock.py ends here; not part of the controller's deterministic state
        self.command_monotonic: list[float] = []
        self.moves = 0  # movej commands started
        self.safety_since_tick = 0
        self.events: list[str] = []  # server-level faults scheduled by the controller ("drop", "stale")
        self._scheduled: list[tuple[int, str]] = []  # (tick, what)
        self.fault_on_move: dict[int, str] = {}  # move number -> "drop" | "stale" (server faults)
        self._prev_qd = self.motion.qd
        self._pose_cache: tuple[object, tuple[float, ...]] = (None, ())
        self._paused_move: Callable[[], Profile] | None = None  # the path from where the arm stands, on resume
        self._reset_script()

    # ------------------------------------------------------------------ script emulation state
    def _reset_script(self) -> None:
        self.reg_int = 0
        self.reg_float = 0
        self._script_started = False
        self._executing = False
        self._busy: str | None = None  # "move" | "stop": a blocking command waiting for the arm
        self._async_move = False
        self._async_stop = False
        self._async_wr = 0
        self._async_op = 0
        self._move_args: Callable[[], Profile] | None = None  # the running move, from where the arm stands

    @property
    def time_s(self) -> float:
        return self.tick * TICK_S

    def timestamp_us(self) -> float:
        return (self.boot_s + self.time_s) * 1e6

    def _say(self, text: str, level: int = rc.INFO_MESSAGE) -> None:
        self.log.append(text)
        self.message_count += 1
        self.messages.append((self.message_count, text, level))
        del self.messages[:-64]
        del self.log[:-1000]

    # ------------------------------------------------------------------ programs (script ports, dashboard)
    def load_script(self, text: str) -> None:
        """A program arrived on a script port: it replaces the running one (UR Script Manual: a program sent to
        the secondary/real-time interface stops the running program)."""
        with self.lock:
            self.last_script = text
            m = _PROGRAM.search(text)
            name = m.group(1) if m else "<unnamed>"
            self.scripts.append(name)
            if not self.remote_control:  # local mode: programs from the network are not run
                self._say(f"program {name} refused: the robot is in local control", rc.ERROR_MESSAGE)
                return
            self._end_program("replaced by a new program")
            if not _SCRIPT_ID.search(text):
                self._say(
                    f"program {name} received: the mock runs ur_rtde's rtde_control only, ended at once",
                    rc.WARNING_MESSAGE,
                )
                self.program = name
                return
            if self.safety_mode != NORMAL or self.robot_mode != RUNNING:
                self._say("program not started: the robot is not running in normal mode", rc.ERROR_MESSAGE)
                return
            self._reset_script()
            for kind, value in _REG_OFFSET.findall(text):
                if kind == "int":
                    self.reg_int = int(value)
                else:
                    self.reg_float = int(value)
            self.program = name
            self.runtime_state = PLAYING

    def _end_program(self, why: str) -> None:
        if self.runtime_state in (PLAYING, PAUSED):
            self._say(f"program {self.program} stopped: {why}")
            if self._busy == "move" or self._async_move:
                self.motion.stop(self.stop_decel)
        self.runtime_state = STOPPED
        self._busy, self._async_move, self._async_stop, self._paused_move = None, False, False, None

    def dashboard_stop(self) -> bool:
        with self.lock:
            if self.runtime_state == STOPPED:
                return False
            self._end_program("stop from the dashboard")
            return True

    def dashboard_pause(self) -> bool:
        with self.lock:
            if self.runtime_state != PLAYING:
                return False
            self.runtime_state = PAUSED
            self._pause_motion()
            return True

    def dashboard_play(self) -> bool:
        with self.lock:
            if self.runtime_state == PAUSED and self.safety_mode == NORMAL:
                self.runtime_state = PLAYING
                self._resume_motion()
                return True
            return False  # the mock has no .urp programs to start

    # ------------------------------------------------------------------ safety
    def protective_stop(self, why: str = "injected") -> None:
        with self.lock:
            if self.safety_mode == PROTECTIVE_STOP:
                return
            self.safety_mode = PROTECTIVE_STOP
            self.safety_since_tick = self.tick
            self.motion.stop(self.stop_decel)
            self._say(f"protective stop: {why}", rc.ERROR_MESSAGE)
            self._end_program("protective stop")

    def unlock_protective_stop(self) -> bool:
        with self.lock:
            if self.safety_mode != PROTECTIVE_STOP:
                return True
            if (self.tick - self.safety_since_tick) * TICK_S < self.unlock_delay_s or self.motion.moving:
                return False
            self.safety_mode = NORMAL
            self._say("protective stop released")
            return True

    def safeguard_stop(self) -> None:
        with self.lock:
            if self.safety_mode != NORMAL:
                return
            self.safety_mode = SAFEGUARD_STOP
            self.safety_since_tick = self.tick
            self._say("safeguard stop", rc.WARNING_MESSAGE)
            if self.runtime_state == PLAYING:
                self.runtime_state = PAUSED
            self._pause_motion()

    def safeguard_reset(self) -> None:
        with self.lock:
            if self.safety_mode != SAFEGUARD_STOP:
                return
            self.safety_mode = NORMAL
            if self.runtime_state == PAUSED:
                self.runtime_state = PLAYING
                self._resume_motion()

    def _pause_motion(self) -> None:
        if self.motion.moving and self._move_args is not None:
            self._paused_move = self._move_args
        self.motion.stop(self.stop_decel)

    def _resume_motion(self) -> None:
        if self._paused_move is not None and not self.motion.moving:
            restart, self._paused_move = self._paused_move, None
            self.motion.follow(restart())

    def power(self, on: bool) -> None:
        with self.lock:
            if on:
                if self.robot_mode == POWER_OFF:
                    self.robot_mode = IDLE
            else:
                self._end_program("power off")
                self.motion.stop(self.stop_decel)
                self.robot_mode = POWER_OFF

    def brake_release(self) -> None:
        with self.lock:
            if self.robot_mode in (IDLE, POWER_ON):
                self.robot_mode = RUNNING

    # ------------------------------------------------------------------ RTDE inputs
    def write_inputs(self, values: dict[str, object]) -> None:
        with self.lock:
            for name, v in values.items():
                reg = rc.register(name)
                if reg is None:
                    self.inputs[name] = v
                elif reg[1] == "int":
                    self.in_int[reg[2]] = int(v)  # type: ignore[call-overload]
                elif reg[1] == "double":
                    self.in_double[reg[2]] = float(v)  # type: ignore[arg-type]
                else:
                    bit = 1 << reg[2]
                    self.in_bits = (self.in_bits | bit) if v else (self.in_bits & ~bit)

    # ------------------------------------------------------------------ the tick
    def step(self) -> None:
        with self.lock:
            self.tick += 1
            self._prev_qd = self.motion.qd
            for when, what in list(self._scheduled):
                if when <= self.tick:
                    self._scheduled.remove((when, what))
                    if what == "protective_stop":
                        self.protective_stop(f"injected mid-move (move {self.moves})")
                    else:
                        self.events.append(what)
            self.motion.step()
            if self.runtime_state == PLAYING:
                self._script_cycle()

    def _write_async(self, value: int) -> None:
        """write_async_progress_register of the 1.6.5 script."""
        self._async_wr = 0 if self._async_wr + 1 > 127 else self._async_wr + 1
        if value == 0:
            self._async_op = 0 if self._async_op + 1 > 127 else self._async_op + 1
        reg = self._async_wr * 65536 + self._async_op * 16777216
        if value >= 0:
            reg += min(value, 32767) + 32768
        self.out_int[2 + self.reg_int] = reg

    def _script_cycle(self) -> None:
        off = self.reg_int
        if not self._script_started:  # script start: reset_async_progress(); signal_ready()
            self._script_started = True
            self._write_async(-1)
            self.out_int[off] = 1
            self._say("RTDE Control Script Loaded (14.02.2024-12:23)")
        if self._async_move and not self.motion.moving and self._paused_move is None:
            self._async_move = False
            self._write_async(-1)  # move_thread: signal_async_operation_finished()
        if self._async_stop and not self.motion.moving:
            self._async_stop = False
            self._write_async(-1)  # stop_thread: signal_async_operation_finished()
        if self._busy is not None:
            if self.motion.moving or self._paused_move is not None:
                return
            self._busy = None
            self.out_int[off] = 2  # signal_done_with_cmd()
            return
        cmd = self.in_int[off]
        if cmd in REALTIME_CMDS:
            self._unsupported(cmd)
        elif cmd == 0:
            self._executing = False
            self.out_int[off] = 1
        elif not self._executing:
            self._executing = True
            self.commands.append(cmd)
            self.command_monotonic.append(time.monotonic())
            self._process(cmd)
            if self.runtime_state == PLAYING and self._busy is None and cmd != STOP_SCRIPT:
                self.out_int[off] = 2

    def _floats(self, first: int, n: int) -> tuple[float, ...]:
        return tuple(self.in_double[first + self.reg_float + i] for i in range(n))

    def _process(self, cmd: int) -> None:
        off = self.reg_int
        if cmd == MOVEJ:
            q, (v, a) = self._floats(0, 6), self._floats(6, 2)
            asynchronous = self.in_int[1 + off] == 1
            self._stop_async_move()
            if any(not (lo <= x <= hi) for x, (lo, hi) in zip(q, self.limits, strict=True)) or not (v > 0 and a > 0):
                self._runtime_error(f"movej({list(q)}, a={a}, v={v}): target outside the joint limits or bad speed")
                return
            self._start_move(lambda: Path(self.motion.q, q, v, a, self.motion.vmax), asynchronous)
        elif cmd == MOVEL:  # exec movel: pose in double 0..5, tool speed 6, tool acceleration 7, async flag int 1
            pose, (v, a) = self._floats(0, 6), self._floats(6, 2)
            asynchronous = self.in_int[1 + off] == 1
            self._stop_async_move()

            def line() -> LinearPath:
                return LinearPath(self.motion.q, pose, v, a, self.calibration, self.tcp, self.motion.vmax, self.limits)

            try:
                first = line()  # what a real controller finds out on the way, the mock before the arm moves
            except ValueError as exc:
                self._runtime_error(f"movel({list(pose)}, a={a}, v={v}): {exc}")
                return
            self._start_move(line, asynchronous, first)
        elif cmd in (STOPJ, STOPL):  # exec_stopl_stopj: deceleration in double 0, async flag in int 1
            decel = self._floats(0, 1)[0]
            decel = decel if decel > 0 else self.stop_decel
            stop_move = not self._async_stop  # a running async stop already stops the move
            if self._async_stop:  # kill stop_thrd: signal_async_operation_finished()
                self._async_stop = False
                self._write_async(-1)
            if stop_move:
                self._stop_async_move(decel)
            if self.in_int[1 + off] == 1:  # stop_thrd = run stop_thread(): started now, finished when still
                self._async_stop = True
                self._write_async(0)
                self.motion.stop(decel)
            elif self.motion.moving:
                self.motion.stop(decel)
                self._busy = "stop"
        elif cmd == PROTECTIVE_STOP_CMD:
            self.protective_stop("protective_stop() called by the script")
        elif cmd == STOP_SCRIPT:
            self._say("RTDE Control Script Terminated")
            self.runtime_state = STOPPED
        elif cmd == SET_PAYLOAD:
            self.payload = self._floats(0, 1)[0]
        elif cmd == SET_TCP:
            self.tcp = self._floats(0, 3)
        elif cmd == SET_WATCHDOG:
            self.watchdog_set = True  # recorded only: the mock does not stop on a missing watchdog update
        elif cmd == IS_JOINTS_WITHIN_LIMITS:
            q = self._floats(0, 6)
            ok = all(lo <= x <= hi for x, (lo, hi) in zip(q, self.limits, strict=True))
            self.out_int[1 + off] = 1 if ok else 0
        elif cmd == IS_STEADY:
            self.out_int[1 + off] = 0 if self.motion.moving else 1
        elif cmd in (GET_FK_DEFAULT, GET_FK_ARGS, GET_TCP_OFFSET):
            if cmd == GET_TCP_OFFSET:
                pose = (*self.tcp, 0.0, 0.0, 0.0)
            elif cmd == GET_FK_DEFAULT:
                pose = tcp_pose(self.motion.q, self.calibration, self.tcp)
            else:
                pose = tcp_pose(self._floats(0, 6), self.calibration, self._floats(6, 3))
            for i, v in enumerate(pose):
                self.out_double[i + self.reg_float] = v
        else:
            self._unsupported(cmd)

    def _start_move(self, path: Callable[[], Profile], asynchronous: bool, first: Profile | None = None) -> None:
        """movej / movel: the path (made from where the arm stands, again on a resume), its faults, its answer."""
        self.moves += 1
        self._move_args = path
        self.motion.follow(first or path())
        if self.moves == self.protective_stop_on_move:
            if self.motion.path is None:  # the arm stands at the target: the stop comes with the command
                self.protective_stop(f"injected at move {self.moves}")
                return
            self._scheduled.append((self.tick + max(1, round(self.motion.path.total / 2 / TICK_S)), "protective_stop"))
        if self.moves in self.fault_on_move and self.motion.path is not None:
            half = max(1, round(self.motion.path.total / 2 / TICK_S))
            self._scheduled.append((self.tick + half, self.fault_on_move[self.moves]))
        if asynchronous:
            self._async_move = True
            self._write_async(0)  # signal_async_operation_started()
        else:
            self._busy = "move"

    def _stop_async_move(self, decel: float | None = None) -> None:
        """stop_async_move() of the script: kills the move thread (the arm brakes) and signals it finished."""
        if self._async_move:
            self._async_move = False
            self.motion.stop(decel if decel and decel > 0 else self.stop_decel)
            self._write_async(-1)

    def _unsupported(self, cmd: int) -> None:
        self._runtime_error(f"command {cmd} of the control script is not emulated by the mock controller")

    def _runtime_error(self, text: str) -> None:
        self._say(text, rc.ERROR_MESSAGE)
        self._end_program("runtime error")

    # ------------------------------------------------------------------ outputs
    @property
    def robot_status_bits(self) -> int:
        bits = 1 if self.robot_mode in (POWER_ON, IDLE, RUNNING, 6) else 0
        return bits | (2 if self.runtime_state == PLAYING else 0)

    @property
    def safety_status_bits(self) -> int:
        return SAFETY_BITS.get(self.safety_mode, 1 << 10)

    def value(self, name: str) -> object:
        """Current value of an RTDE output variable (caller holds the lock)."""
        reg = rc.register(name)
        if reg is not None:
            kind, typ, i = reg
            if typ == "int":
                return (self.out_int if kind == "output" else self.in_int)[i]
            if typ == "double":
                return (self.out_double if kind == "output" else self.in_double)[i]
            return bool(((self.out_bits if kind == "output" else self.in_bits) >> i) & 1)
        q, qd = self.motion.q, self.motion.qd
        if name == "timestamp":
            return self.boot_s + self.time_s
        if name in ("actual_q", "target_q"):
            return q
        if name in ("actual_qd", "target_qd"):
            return qd
        if name == "target_qdd":
            return tuple((a - b) / TICK_S for a, b in zip(qd, self._prev_qd, strict=True))
        if name in ("actual_TCP_pose", "target_TCP_pose"):
            if self._pose_cache[0] != (q, self.tcp):
                self._pose_cache = ((q, self.tcp), tcp_pose(q, self.calibration, self.tcp))
            return self._pose_cache[1]
        if name in ("actual_TCP_speed", "target_TCP_speed"):
            if not any(qd):
                return (0.0,) * 6
            return tcp_speed(q, qd, self.calibration, self.tcp, TICK_S)
        if name == "robot_mode":
            return self.robot_mode
        if name == "joint_mode":
            return (JOINT_RUNNING_MODE if self.robot_mode == RUNNING else 236,) * 6  # 236: JOINT_POWER_OFF_MODE
        if name in ("safety_mode", "safety_status"):
            return self.safety_mode
        if name == "runtime_state":
            return self.runtime_state
        if name == "robot_status_bits":
            return self.robot_status_bits
        if name == "safety_status_bits":
            return self.safety_status_bits
        if name == "speed_scaling":
            return 1.0 if self.safety_mode == NORMAL and self.runtime_state != PAUSED else 0.0
        if name == "target_speed_fraction":
            return 1.0
        if name == "joint_temperatures":
            return self.temperatures
        if name == "actual_execution_time":
            return 0.35  # ms of the controller's real-time thread per cycle (order of what UR reports)
        if name in ("actual_main_voltage", "actual_robot_voltage"):
            return 48.0
        if name == "actual_joint_voltage":
            return (47.6,) * 6
        if name == "actual_tool_accelerometer":
            return (0.0, 0.0, -9.81)
        if name == "payload":
            return self.payload
        if name == "input_bit_registers0_to_31":
            return self.in_bits & 0xFFFFFFFF
        if name == "input_bit_registers32_to_63":
            return (self.in_bits >> 32) & 0xFFFFFFFF
        if name == "output_bit_registers0_to_31":
            return self.out_bits & 0xFFFFFFFF
        if name == "output_bit_registers32_to_63":
            return (self.out_bits >> 32) & 0xFFFFFFFF
        typ = rc.OUTPUTS[name]
        zero = {"DOUBLE": 0.0, "BOOL": False}.get(typ, 0)
        n = len(rc.TYPE_FORMAT[typ])
        return tuple(0.0 if typ.endswith("D") else 0 for _ in range(n)) if n > 1 else zero

    def values(self, names: Sequence[str]) -> dict[str, object]:
        with self.lock:
            return {n: self.value(n) for n in names}

    def state(self) -> dict:
        """Summary for the control port and tests (JSON-able)."""
        with self.lock:
            return {
                "tick": self.tick,
                "q": list(self.motion.q),
                "moving": self.motion.moving,
                "robot_mode": ROBOT_MODE[self.robot_mode],
                "safety_mode": SAFETY_MODE[self.safety_mode],
                "runtime_state": self.runtime_state,
                "program": self.program,
                "moves": self.moves,
                "commands": list(self.commands),
                "command_monotonic": self.command_monotonic[-20:],
                "scripts": list(self.scripts),
                "log": self.log[-20:],
                "out_int": self.out_int[:4],
                "in_int": self.in_int[:2],
                "busy": self._busy,
                "reg_offset": [self.reg_int, self.reg_float],
                "out_int_upper": self.out_int[24:28],
                "executing": self._executing,
                "async_move": self._async_move,
            }
