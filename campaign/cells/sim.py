"""The digital twin's cell: its mock servers on loopback (shared by `run --sim` and `trackcal mock`) and, for
`run --sim`, the real clients talking to them. The real cell: campaign/cells/hardware.py."""

from __future__ import annotations

import contextlib
import socket
import time
from collections.abc import Callable

from trackcal.calib.model.cell import Cell
from trackcal.campaign.cells.checks import cell_box_check, joint_limits_deg, motion_guard, robot_limits_deg
from trackcal.campaign.cells.operator import PlcOperator
from trackcal.campaign.engine.engine import Live
from trackcal.campaign.errors import InputError
from trackcal.campaign.session.session import measured_keys
from trackcal.campaign.session.store import SessionStore
from trackcal.drivers.emscon.client import EmsconTracker
from trackcal.drivers.kuka.client import KukaKrc2
from trackcal.drivers.meteo.client import SerialMeteo
from trackcal.drivers.plc.client import ModbusCellIO
from trackcal.mocks.cell import World
from trackcal.mocks.clock import VirtualClock
from trackcal.mocks.controllers import twin_controllers
from trackcal.mocks.operator import SimHuman
from trackcal.mocks.servers.emscon import MockEmscon
from trackcal.mocks.servers.emscon_identity import twin_identity
from trackcal.mocks.servers.kuka.controller import MockKrc2
from trackcal.mocks.servers.meteo import MockMeteo
from trackcal.mocks.servers.plc import MockPlc
from trackcal.mocks.twin import Twin

HOME_DEG = (0.0, -90.0, 90.0, 0.0, 90.0, 0.0)  # KR C2 HOME of the KRL program (configs/krc2)
# Rated axis speeds of a KR 270 are about 100 deg/s for A1-A3 (KUKA KR QUANTEC data sheet: A1 105, A2 101,
# A3 96 deg/s); the slowest of them sets the simulated PTP duration at 100 % override.
SIM_JOINT_SPEED_DEG_S = 96.0


class TwinMocks:
    """The digital twin's cell behind the real protocols, for `run --sim` (SimCell, same process) and `trackcal
    mock` (another process): emScon tracker server, Modbus cell PLC with the simulated operator at its lamp (he
    reads the request registers: the PLC is his only channel), serial meteo on a pseudo-terminal, all on
    loopback, and the KR C2 controller, which like the real one is a client: `serve_controller` points it at
    the EKI and RSI ports trackcal listens on.

    `measured`: (station, point, joints) of the measurements a resumed session already holds, so every
    measurement keeps its noise (a pure function of the seed and the step's identity). `speed`: simulated
    seconds per real second (None: as fast as the machine goes). `hold_s`: the least time the simulated operator
    holds the acknowledge button (he holds it until the request lamp goes out)."""

    def __init__(
        self,
        cell: Cell,
        seed: int,
        effects: dict[str, float] | None = None,
        speed: float | None = None,
        measured=None,
        hold_s: float = 0.05,
        human_acknowledges: bool = True,
    ) -> None:
        if cell.chain.dof != len(HOME_DEG):
            raise InputError(
                f"cell {cell.name}: the simulated KR C2 drives 6 axes, robot {cell.chain.name} has {cell.chain.dof}"
            )
        self.cell, self.seed, self.speed = cell, seed, speed
        self.clock = VirtualClock(real_fraction=0.0 if not speed else 1.0 / speed)
        self.world = World(Twin(cell, seed=seed, effects=effects or {}), self.clock)
        if measured:
            self.world.restore_counts(measured)
        self.controller: MockKrc2 | None = None
        self.family_controller = None  # a twin controller of mocks/controllers.py (serve_family)
        self._started: list = []
        try:
            self.tracker_mock = self._up(
                MockEmscon(
                    lambda expected: self.world.measure(),
                    self.clock,
                    reflector_present=self.world.reflector_visible,
                    identity=twin_identity(cell.tracker.key, seed),
                ).start()
            )
            self.plc = self._up(MockPlc(clock=self.clock).start())
            self.meteo_mock = self._up(MockMeteo(seed, self.clock).start())
            self.human = self._up(
                SimHuman(self.world, self.plc, hold_s=hold_s, acknowledges=human_acknowledges).start()
            )
        except BaseException:
            self.close()
            raise

    def _up(self, device):
        self._started.append(device)
        return device

    def serve_controller(
        self,
        eki_addr: tuple[str, int],
        rsi_addr: tuple[str, int],
        connect_timeout_s: float = 20.0,
        delivered=None,
        skip_idle: bool = True,
    ) -> None:
        """Start the mock KR C2, connecting (and retrying for connect_timeout_s) to trackcal's EKI and RSI ports.
        Whenever trackcal goes away (exited, killed) the controller keeps the robot where it stands and connects
        again, as trackcal_eki.src closes and reopens its channel: the next trackcal finds it. The RSI stream is
        the shipped configuration's (configs/krc2/trackcal_rsi.xml). `delivered` (the client's frame_received,
        when it runs in this process on this clock) puts the controller in lockstep with it, skipping the idle
        cycles nobody reads unless not skip_idle (mocks.servers.kuka.controller)."""
        self.controller = MockKrc2(
            eki_addr,
            rsi_addr,
            self.clock,
            HOME_DEG,
            on_joints=self.world.robot_at,
            joint_speed_deg_s=SIM_JOINT_SPEED_DEG_S,
            seed=self.seed,
            overshoot_deg=0.0,
            soft_limits_deg=robot_limits_deg(self.cell),
            connect_timeout_s=connect_timeout_s,
            delivered=delivered,
            skip_idle=skip_idle,
        ).start()

    def serve_family(self, family: str) -> dict:
        """Start the twin's controller of robot family `family` (mocks/controllers.py: the controller's own
        protocols, in a process of its own where the family needs one); returns the hardware file's robot section
        for it. InputError when no mock serves that family."""
        served = twin_controllers()
        if family not in served:
            raise InputError(
                f"cell {self.cell.name}: no mock controller for the robot's controller {family!r} "
                f"(mocks serve: {', '.join(served) or 'none'})"
            )
        self.world.robot_at(self.world.q_deg if self.world.q_deg.any() else HOME_DEG)
        self.family_controller = served[family].serve(self.world, self.seed, self.speed)
        return self.family_controller.hardware()

    def controllers_connected(self) -> int:
        """How many times the controller connected to trackcal (one per `run` / `resume` served)."""
        return 0 if self.controller is None else self.controller.connections

    def addresses(self) -> dict[str, str]:
        """Where each mock serves (for people)."""
        host, port = self.tracker_mock.address
        phost, pport = self.plc.address
        out = {
            "tracker (emScon)": f"{host}:{port}",
            "cell PLC (Modbus TCP)": f"{phost}:{pport} unit {self.plc.unit_id}",
            "meteo (serial)": self.meteo_mock.port_path,
        }
        if self.family_controller is not None:
            out.update(self.family_controller.addresses())
        if self.controller is not None:
            out["KR C2 connects to EKI"] = "{}:{}".format(*self.controller.eki_addr)
            out["KR C2 connects to RSI"] = "{} {}:{}".format(self.controller.rsi_protocol, *self.controller.rsi_addr)
        return out

    def stop_controller(self) -> None:
        """The controller stops: its connections end as a controller switched off."""
        if self.controller is not None:
            with contextlib.suppress(Exception):
                self.controller.stop()
        if self.family_controller is not None:
            with contextlib.suppress(Exception):
                self.family_controller.stop()

    def close(self) -> None:
        """The controller first, then the other mocks in reverse order of start; one failing stop never keeps
        the others up."""
        self.stop_controller()
        for dev in reversed(self._started):
            with contextlib.suppress(Exception):
                dev.stop()
        self._started = []


class SimCell:
    """The digital twin's cell (TwinMocks) with the real clients talking to it over loopback in `live`. The
    mocks stay reachable (tracker_mock, controller, plc, meteo_mock, human, world, clock) so tests can inject
    faults mid-campaign.

    On resume the world learns which measurements the session already holds, so every measurement keeps its
    noise (a pure function of the seed and the step's identity). `speed`: simulated seconds per real second
    (None: as fast as the machine goes).

    The controller runs in lockstep with the robot client (both on the virtual clock): the clock, so every
    timestamp, depends on the commands only, and the cycles the robot stands through unread are skipped;
    `skip_idle=False` exchanges every one of them (the same session, byte for byte, only slower). `lockstep=False`
    runs the controller free, as `trackcal mock` serves it to another process: every cycle, paced by wall time,
    so the timestamps depend on the machine's pace (the measurements do not). `say`: where the operator's requests
    are shown (the console of `trackcal run --sim`; nowhere by default: the simulated operator reads the HMI)."""

    def __init__(
        self,
        cell: Cell,
        seed: int,
        store: SessionStore | None = None,
        effects: dict[str, float] | None = None,
        speed: float | None = None,
        skip_idle: bool = True,
        lockstep: bool = True,
        say: Callable[[str], None] = lambda text: None,
        human_acknowledges: bool = True,
    ) -> None:
        self.mocks = TwinMocks(
            cell,
            seed,
            effects,
            speed,
            None if store is None else measured_keys(store),
            human_acknowledges=human_acknowledges,
        )
        m = self.mocks
        self.clock, self.world, self.tracker_mock, self.plc = m.clock, m.world, m.tracker_mock, m.plc
        self.meteo_mock, self.human = m.meteo_mock, m.human
        self._clients: list = []
        try:
            tracker = self._client(EmsconTracker(*self.tracker_mock.address, timeout_s=10.0))
            cellio = self._client(ModbusCellIO(*self.plc.address, timeout_s=5.0))
            robot = self._client(
                KukaKrc2(
                    "127.0.0.1",
                    0,
                    "127.0.0.1",
                    0,
                    controller_host="127.0.0.1",
                    joint_limits_deg=joint_limits_deg(cell),
                    cell_box_check=cell_box_check(cell),
                    motion_guard=motion_guard(cellio),
                    connect_timeout_s=20.0,
                )
            )
            robot.listen()
            m.serve_controller(
                robot.eki.address,
                robot.rsi.address,
                skip_idle=skip_idle,
                delivered=robot.rsi.frame_received if lockstep else None,
            )
            self.controller = m.controller
            if lockstep:
                robot.rsi.sync = self.controller.sync
            meteo = self._client(SerialMeteo(self.meteo_mock.port_path, timeout_s=5.0))
            for dev in (tracker, robot, cellio, meteo):
                dev.connect()
        except BaseException:
            self.close()
            raise
        operator = PlcOperator(cellio, say, poll_s=0.005)
        if not human_acknowledges:
            operator = HumanFirst(operator, self.human)
        self.live = Live(tracker, robot, operator, self.clock, cellio, meteo, close=self.close)

    def _client(self, device):
        self._clients.append(device)
        return device

    def close(self) -> None:
        """The controller first (it is the one that hangs up, not trackcal), then the clients, then the other
        mocks; one failing close never keeps the others up."""
        self.mocks.stop_controller()
        for dev in reversed(self._clients):
            with contextlib.suppress(Exception):
                dev.close()
        self._clients = []
        self.mocks.close()


class HumanFirst:
    """The cell's request (PlcOperator) shared with other operators while the simulated person does the work
    but leaves the acknowledgement to them (`run --sim --operator web`): the request is offered to the others
    only once he has done it and closed the door, as a person answers on the tablet once the reflector is in its
    nest. (Without this wait an answer could overtake him, and the tracker would measure a station or point he has
    not set up yet.)"""

    def __init__(self, plc: PlcOperator, human, timeout_s: float = 60.0) -> None:
        self.plc, self.human, self.timeout_s = plc, human, timeout_s

    def offer(self, kind: str, target: str, text: str) -> None:
        before = self.human.acted
        self.plc.offer(kind, target, text)
        deadline = time.monotonic() + self.timeout_s
        while self.human.acted == before and time.monotonic() < deadline:
            time.sleep(0.002)

    def poll(self) -> str | None:
        return self.plc.poll()

    def withdraw(self) -> None:
        self.plc.withdraw()

    def ask(self, kind: str, target: str, text: str) -> str:
        return self.plc.ask(kind, target, text)


# How often trackcal reads the acknowledge button (written into the hardware file); the simulated operator holds
# it until the request lamp goes out, as a person would, so no press is missed at any poll period.
POLL_S = 0.05
# The controller retries its first connection this long before giving up.
CONTROLLER_CONNECT_S = 24 * 3600.0


def free_port(kind: int = socket.SOCK_STREAM, host: str = "127.0.0.1") -> int:
    """A port nobody listens on now (the OS picks it); trackcal binds it later with SO_REUSEADDR."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def krc2_robot_doc(mocks: TwinMocks, eki: tuple[str, int], rsi: tuple[str, int]) -> dict:
    """The hardware file's robot section for the twin's KR C2 (serve_controller), which connects to eki and rsi."""
    return {
        "protocol": "krc2",
        "controller_host": "127.0.0.1",
        "eki": {"host": eki[0], "port": eki[1]},
        "rsi": {
            "protocol": mocks.controller.rsi_protocol,
            "passive": mocks.controller.rsi_passive,
            "host": rsi[0],
            "port": rsi[1],
        },
        "connect_timeout_s": 30.0,
    }


def hardware_doc(mocks: TwinMocks, robot: dict) -> dict:
    """The hardware config (campaign/cells/hardware.py schema) of the running mocks, with `robot` its robot
    section."""
    thost, tport = mocks.tracker_mock.address
    phost, pport = mocks.plc.address
    return {
        # the twin's tracker serial (mocks/servers/emscon_identity.py): what it reports, so a run finds it as stated
        "tracker": {
            "protocol": "emscon",
            "host": thost,
            "port": tport,
            "timeout_s": 10.0,
            "serial": str(mocks.tracker_mock.identity.serial_number),
        },
        "robot": robot,
        "plc": {
            "protocol": "modbus",
            "host": phost,
            "port": pport,
            "unit_id": mocks.plc.unit_id,
            "timeout_s": 2.0,
            "poll_s": POLL_S,
        },
        "meteo": {"protocol": "serial", "port": mocks.meteo_mock.port_path, "baudrate": 9600, "timeout_s": 2.0},
    }
