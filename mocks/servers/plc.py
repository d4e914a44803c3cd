"""Mock cell PLC: a real pymodbus Modbus TCP server on 127.0.0.1, run from a background thread.

    plc = MockPlc().start()          # free port chosen by the OS
    host, port = plc.address
    plc.close_door(); plc.press_acknowledge(); plc.lamp  # test hooks (thread-safe)
    plc.inject(PlcFault.EXCEPTION, code=0x06)            # fault injection
    plc.stop()

The register map is drivers.plc.PlcRegisterMap (configs/hardware/cell-plc-registers.md).

How it is built on pymodbus 3.16.1 (installed source read; the datastore API changed across 3.x):
- Since 3.13 the datastore is `SimDevice`/`SimData` (pymodbus/simulator/simdevice.py, simdata.py; release
  notes 3.13.0 "Datastores uses SimData/SimDevice"); ModbusServerContext/ModbusDeviceContext still exist but
  log a deprecation warning and are converted to SimDevice internally (datastore/context.py).
- The server keeps the register values inside its private SimCore/SimRuntime (pymodbus discussion #2966), so
  the test hooks do not poke them. The one public entry point is `SimDevice(action=...)`: an async callback
  run on every access with the live register list ("modify inline") and the values being written, which may
  return an ExcCodes member to answer with a Modbus exception (simdevice.py, SimAction). This mock keeps the
  authoritative state in Python under a lock and syncs it in that callback.
- Non-shared blocks: `simdata=(coils, discrete inputs, holding, input)` with BITS blocks addressed per bit,
  packed 16 per register, bit 0 first (simulator/simutils.py, registersToBits).
- `ModbusTcpServer(context, address=(host, 0))` listens with loop.create_server, so port 0 gets a free port;
  the bound socket is `server.transport.sockets[0]` (transport/transport.py, listen).
- Fault hooks use the per-connection handler made by `callback_new_connection` (server/base.py) and its
  `trace_packet(sending, data) -> data` hook, which may rewrite the byte stream
  (transaction/transaction.py): returning b"" for an outgoing answer silences it.
"""

from __future__ import annotations

import asyncio
import enum
import threading

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from trackcal.drivers.interfaces import RealClock
from trackcal.drivers.plc.codec import (
    DEFAULT_REGISTER_MAP,
    REQUEST_REGISTERS,
    STATUS_ESTOP_OK,
    STATUS_RUN,
    STATUS_WATCHDOG_EXPIRED,
    OperatorRequest,
    PlcRegisterMap,
    decode_request,
    encode_request,
)
from trackcal.mocks.clock import VirtualClock

FC_READ_COILS, FC_READ_DI, FC_READ_HR, FC_READ_IR = 1, 2, 3, 4
FC_WRITE_COIL, FC_WRITE_REG, FC_WRITE_COILS, FC_WRITE_REGS = 5, 6, 15, 16


class PlcFault(enum.Enum):
    NONE = "none"
    SILENT = "silent"  # requests are processed but no answer is ever sent
    DROP = "drop"  # every incoming request makes the PLC close that connection without answering
    EXCEPTION = "exception"  # every request is answered with a Modbus exception response (code given)


class _FaultyTcpServer(ModbusTcpServer):
    """ModbusTcpServer whose connection handlers route their byte stream through the mock's fault hook."""

    def __init__(self, owner: MockPlc, *args, **kwargs) -> None:
        self._owner = owner
        super().__init__(*args, **kwargs)

    def callback_new_connection(self):
        handler = super().callback_new_connection()
        owner = self._owner

        def trace_packet(sending: bool, data: bytes) -> bytes:
            return owner._trace_packet(handler, sending, data)

        handler.trace_packet = trace_packet
        owner.connections += 1
        return handler


class MockPlc:
    def __init__(
        self,
        unit_id: int = 1,
        register_map: PlcRegisterMap = DEFAULT_REGISTER_MAP,
        clock: RealClock | VirtualClock | None = None,
        watchdog_s: float = 2.0,
        host: str = "127.0.0.1",
        port: int = 0,
    ) -> None:
        self.unit_id = unit_id
        self.map = register_map
        self.clock = clock if clock is not None else VirtualClock()
        self.watchdog_s = watchdog_s
        self.connections = 0  # connections accepted so far
        self._host, self._port = host, port
        self._lock = threading.Condition()  # notified when trackcal writes the request lamp or registers
        self._requests_written = 0  # how many times it did (wait_request_written)
        self._door_closed = False  # a cell starts with its door open
        self._acknowledge = False
        self._lamp = False
        self._estop_ok = True
        self._heartbeat = 0
        self._heartbeat_changed_at = self.clock.now()
        self._request = encode_request(None, 0)  # the HMI request registers (drivers.plc.encode_request)
        self._fault = PlcFault.NONE
        self._fault_code = ExcCodes.DEVICE_FAILURE
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: _FaultyTcpServer | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._start_error: BaseException | None = None

    # ------------------------------------------------------------------ lifecycle
    @property
    def address(self) -> tuple[str, int]:
        """(host, port) the server listens on; still valid after stop() (then connections are refused)."""
        if self._port == 0:
            raise RuntimeError("mock PLC not started")
        return self._host, self._port

    def start(self, timeout_s: float = 5.0) -> MockPlc:
        if self._thread is not None:
            return self
        self._thread = threading.Thread(target=self._run, name="mock-plc", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise RuntimeError("mock PLC did not start in time")
        if self._start_error is not None:
            raise RuntimeError(f"mock PLC failed to start: {self._start_error}") from self._start_error
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        loop, thread = self._loop, self._thread
        if loop is None or thread is None:
            return
        if self._server is not None and loop.is_running():
            asyncio.run_coroutine_threadsafe(self._server.shutdown(), loop).result(timeout_s)
            loop.call_soon_threadsafe(loop.stop)
        thread.join(timeout_s)
        self._thread = None
        self._server = None

    def __enter__(self) -> MockPlc:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(self._listen())
        except BaseException as exc:  # reported to start()
            self._start_error = exc
            self._ready.set()
            loop.close()
            return
        self._ready.set()
        try:
            loop.run_forever()
        finally:
            pending = asyncio.all_tasks(loop)
            for task in pending:
                task.cancel()
            loop.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
            loop.close()

    async def _listen(self) -> None:
        server = _FaultyTcpServer(self, self._device(), address=(self._host, self._port))
        await server.serve_forever(background=True)
        self._port = server.transport.sockets[0].getsockname()[1]
        self._server = server

    def _device(self) -> SimDevice:
        m = self.map
        di_lo = min(m.door_closed_di, m.acknowledge_di)
        di_hi = max(m.door_closed_di, m.acknowledge_di)
        ir_lo = min(m.status_ir, m.map_version_ir)
        ir_hi = max(m.status_ir, m.map_version_ir)
        return SimDevice(
            id=self.unit_id,
            simdata=(
                [SimData(address=m.request_lamp_coil, values=[False], datatype=DataType.BITS)],
                [SimData(address=di_lo, values=[False] * (di_hi - di_lo + 1), datatype=DataType.BITS)],
                sorted(
                    [
                        SimData(address=m.heartbeat_hr, values=[0], datatype=DataType.REGISTERS),
                        SimData(address=m.request_hr, values=[0] * REQUEST_REGISTERS, datatype=DataType.REGISTERS),
                    ],
                    key=lambda d: d.address,
                ),
                [SimData(address=ir_lo, values=[0] * (ir_hi - ir_lo + 1), datatype=DataType.REGISTERS)],
            ),
            action=self._action,
        )

    # ------------------------------------------------------------------ test hooks
    def open_door(self) -> None:
        with self._lock:
            self._door_closed = False

    def close_door(self) -> None:
        with self._lock:
            self._door_closed = True

    def press_acknowledge(self) -> None:
        with self._lock:
            self._acknowledge = True

    def release_acknowledge(self) -> None:
        with self._lock:
            self._acknowledge = False

    def set_estop(self, pressed: bool) -> None:
        with self._lock:
            self._estop_ok = not pressed

    @property
    def lamp(self) -> bool:
        with self._lock:
            return self._lamp

    @property
    def door_closed(self) -> bool:
        with self._lock:
            return self._door_closed

    @property
    def operator_request(self) -> OperatorRequest:
        """The operator request trackcal shows on the HMI (kind None: none pending)."""
        with self._lock:
            return decode_request(self._request)

    def wait_request_written(self, seen: int, timeout_s: float) -> int:
        """Until trackcal writes the request lamp or registers after the `seen`-th write (at most timeout_s of wall
        time); returns how many writes there were. The simulated operator waits here instead of looking every few
        milliseconds (issue 41: his looking cost more CPU than the PLC's own serving)."""
        with self._lock:
            self._lock.wait_for(lambda: self._requests_written != seen, timeout_s)
            return self._requests_written

    @property
    def heartbeat(self) -> int:
        with self._lock:
            return self._heartbeat

    def inject(self, fault: PlcFault, code: int = ExcCodes.DEVICE_FAILURE) -> None:
        """Switch a fault on until clear_fault(). `code` is the Modbus exception code for EXCEPTION."""
        with self._lock:
            self._fault = fault
            self._fault_code = ExcCodes(code)

    def clear_fault(self) -> None:
        self.inject(PlcFault.NONE)

    # ------------------------------------------------------------------ server side
    def _status_word_locked(self) -> int:
        word = STATUS_RUN
        if self._estop_ok:
            word |= STATUS_ESTOP_OK
        if self.clock.now() - self._heartbeat_changed_at > self.watchdog_s:
            word |= STATUS_WATCHDOG_EXPIRED
        return word

    def _trace_packet(self, handler, sending: bool, data: bytes) -> bytes:
        with self._lock:
            fault = self._fault
        if sending and fault is PlcFault.SILENT:
            return b""
        if not sending and fault is PlcFault.DROP:
            assert self._loop is not None
            self._loop.call_soon(handler.close)
            return b""
        return data

    async def _action(self, fc, start_address, address, _count, registers, set_values) -> ExcCodes | None:
        """SimDevice action: runs in the server loop on every access; syncs the registers with our state."""
        m = self.map
        with self._lock:
            if self._fault is PlcFault.EXCEPTION:
                return self._fault_code
            if fc == FC_READ_DI:
                self._put_bit(registers, start_address, m.door_closed_di, self._door_closed)
                self._put_bit(registers, start_address, m.acknowledge_di, self._acknowledge)
            elif fc in (FC_READ_COILS, FC_WRITE_COIL, FC_WRITE_COILS):
                for i, value in enumerate(set_values or ()):
                    if address + i == m.request_lamp_coil:
                        self._lamp = bool(value)
                        self._request_written()
                self._put_bit(registers, start_address, m.request_lamp_coil, self._lamp)
            elif fc in (FC_WRITE_REG, FC_WRITE_REGS):
                for i, value in enumerate(set_values or ()):
                    if address + i == m.heartbeat_hr and value != self._heartbeat:
                        self._heartbeat = int(value)
                        self._heartbeat_changed_at = self.clock.now()
                    elif 0 <= address + i - m.request_hr < REQUEST_REGISTERS:
                        self._request[address + i - m.request_hr] = int(value)
                        self._request_written()
            elif fc == FC_READ_HR:
                for i, value in enumerate(self._request):
                    if 0 <= m.request_hr + i - start_address < len(registers):
                        registers[m.request_hr + i - start_address] = value
            elif fc == FC_READ_IR:
                registers[m.status_ir - start_address] = self._status_word_locked()
                registers[m.map_version_ir - start_address] = m.map_version
        return None

    def _request_written(self) -> None:
        """With the lock held."""
        self._requests_written += 1
        self._lock.notify_all()

    @staticmethod
    def _put_bit(registers: list[int], start_register: int, bit_address: int, value: bool) -> None:
        index, bit = bit_address // 16 - start_register, bit_address % 16
        if value:
            registers[index] |= 1 << bit
        else:
            registers[index] &= ~(1 << bit) & 0xFFFF
