"""Cell PLC over Modbus TCP (pymodbus synchronous client) implementing drivers.interfaces.CellIO.

Register map: configs/hardware/cell-plc-registers.md (mirrored by drivers.plc.codec.PlcRegisterMap). All
addresses are the 0-based PDU addresses that go on the wire.

SAFETY: `door_closed()` never reports a closed door it could not read. Any failure (not connected, timeout,
connection lost, exception response, malformed answer) makes it return False (= door OPEN) and records the
error in `last_door_error`; the campaign engine then behaves as if someone were in the cell.
Every other call raises a drivers.errors exception on failure:
  ConnectionLost   cannot connect, peer closed/reset        message names host:port and the action
  DeviceTimeout    no answer within timeout_s             the socket is dropped; the next call reconnects
  ProtocolError    Modbus exceptions 01/02/03 (our request does not fit the PLC program: wrong map), a
                   wrong map version, a malformed answer
  DeviceFault      Modbus exceptions 04 and up (the PLC refuses: device failure, busy, gateway...),
                   `.code` = the Modbus exception code

pymodbus 3.16.1 behaviour relied upon (installed source, pymodbus/client/tcp.py, client/base.py and
transaction/transaction.py):
- `ModbusTcpClient(host, port=, timeout=, retries=)`: `timeout` bounds both the TCP connect
  (socket.create_connection) and the wait for each answer (`recv` loops on select until its deadline);
  with retries=0 a request is sent once, so one call waits at most ~timeout_s.
- `ModbusBaseSyncClient.execute` connects on demand and raises ConnectionException when it cannot; a peer
  close during a read raises ConnectionException ("Connection unexpectedly closed") and closes the socket,
  so the next call reconnects by itself.
- `TransactionManager.sync_execute` raises ModbusIOException("No response received ...") after the
  retries time out, and ModbusIOException("... request uses device id/transaction id ...") for a reply
  that does not match the request.
- A Modbus exception answer comes back as a pdu whose `isError()` is true, with `.exception_code`.
"""

from __future__ import annotations

import logging
import threading

from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from trackcal.drivers.errors import ConnectionLost, DeviceError, DeviceFault, DeviceTimeout, ProtocolError
from trackcal.drivers.plc.codec import (
    DEFAULT_REGISTER_MAP,
    MODBUS_EXCEPTIONS,
    REQUEST_MISMATCH_CODES,
    REQUEST_REGISTERS,
    OperatorRequest,
    PlcRegisterMap,
    PlcStatus,
    decode_request,
    encode_request,
)
from trackcal.drivers.transport import require_positive

log = logging.getLogger(__name__)


class ModbusCellIO:
    """The cell's door switch, acknowledge button and request lamp, behind the cell PLC."""

    def __init__(
        self,
        host: str,
        port: int = 502,
        unit_id: int = 1,
        timeout_s: float = 1.0,
        register_map: PlcRegisterMap = DEFAULT_REGISTER_MAP,
    ) -> None:
        require_positive(timeout_s=timeout_s)
        self.host = host
        self.port = port
        self.unit_id = unit_id
        self.timeout_s = timeout_s
        self.map = register_map
        self.device = f"cell PLC {host}:{port}"
        self.last_door_error: DeviceError | None = None
        self._heartbeat = 0
        self._request_seq = 0
        self._client: ModbusTcpClient | None = None
        # one request on the socket at a time, and no close in the middle of one: the KR C4's motion guard reads the
        # door from its own thread (drivers.krc4.cycle_guard) while the campaign's thread asks the operator through
        # the same client and closes it at the end (pymodbus' sync client is not thread-safe: a close during the
        # guard's read left its socket None under the read, an AttributeError out of the guard's thread)
        self._lock = threading.Lock()

    # ------------------------------------------------------------------ lifecycle
    def connect(self) -> None:
        """Open the connection and check that the PLC program implements our register-map version."""
        if self._client is None:
            self._client = ModbusTcpClient(
                self.host, port=self.port, timeout=self.timeout_s, retries=0, name="cell-plc"
            )
        if not self._client.connect():
            raise ConnectionLost(
                f"cannot connect (refused or unreachable within {self.timeout_s} s) while connecting",
                device=self.device,
            )
        rr = self._call(
            f"reading the map version (IR {self.map.map_version_ir})",
            self._read_input_registers,
            self.map.map_version_ir,
        )
        version = self._first(rr.registers, "map version")
        if version != self.map.map_version:
            raise ProtocolError(
                f"PLC implements register map 0x{version:04X}, this client expects 0x{self.map.map_version:04X}",
                device=self.device,
            )

    def close(self) -> None:
        with self._lock:
            client, self._client = self._client, None
            if client is not None:
                client.close()

    def __enter__(self) -> ModbusCellIO:
        self.connect()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # ------------------------------------------------------------------ CellIO
    def door_closed(self) -> bool:
        """True only if the PLC positively reports the door closed; any error reads as OPEN (False)."""
        try:
            rr = self._call(
                f"reading door-closed input (DI {self.map.door_closed_di})",
                self._read_discrete_inputs,
                self.map.door_closed_di,
            )
            closed = self._first(rr.bits, "door-closed input") is True
        except DeviceError as exc:
            self.last_door_error = exc
            log.warning("door state unreadable, treated as OPEN: %s", exc)
            return False
        self.last_door_error = None
        return closed

    def acknowledge_pressed(self) -> bool:
        rr = self._call(
            f"reading acknowledge input (DI {self.map.acknowledge_di})",
            self._read_discrete_inputs,
            self.map.acknowledge_di,
        )
        return self._first(rr.bits, "acknowledge input") is True

    def set_request_lamp(self, on: bool) -> None:
        rr = self._call(
            f"writing request lamp coil (coil {self.map.request_lamp_coil}) to {int(on)}",
            self._write_coil,
            self.map.request_lamp_coil,
            bool(on),
        )
        echoed = self._first(rr.bits, "coil echo")
        if echoed is not bool(on):
            raise ProtocolError(f"write-coil echo {echoed} does not match {bool(on)}", device=self.device)

    # ------------------------------------------------------------------ beyond CellIO
    def heartbeat(self) -> int:
        """Write the next heartbeat counter (mod 65536) to the PLC watchdog register; returns it."""
        value = (self._heartbeat + 1) & 0xFFFF
        self._call(
            f"writing heartbeat (HR {self.map.heartbeat_hr})",
            self._write_register,
            self.map.heartbeat_hr,
            value,
        )
        self._heartbeat = value
        return value

    def show_request(self, kind: str, target: str = "") -> int:
        """Publish the pending operator request on the HMI registers (HR request_hr ..): reads the PLC's
        request sequence number and writes kind, sequence + 1 and target in one request, so a new request is
        always told apart from the previous one, even one written by an earlier trackcal process. Returns the
        sequence number written. Call before lighting the request lamp; `clear_request()` after."""
        first = self.map.request_hr
        rr = self._call(
            f"reading the operator request sequence (HR {first + 1})",
            self._read_holding_registers,
            first + 1,
        )
        seq = (self._first(rr.registers, "request sequence") + 1) & 0xFFFF
        values = encode_request(kind, seq, target)
        self._call(
            f"writing the operator request {kind} {target!r} (HR {first}..{first + REQUEST_REGISTERS - 1})",
            self._write_registers,
            first,
            values,
        )
        self._request_seq = seq
        return seq

    def clear_request(self) -> None:
        """No request pending any more (kind 0); the sequence number stays."""
        first = self.map.request_hr
        self._call(
            f"clearing the operator request (HR {first}..{first + REQUEST_REGISTERS - 1})",
            self._write_registers,
            first,
            encode_request(None, self._request_seq),
        )

    def read_request(self) -> OperatorRequest:
        """The request the HMI shows now (what the PLC holds)."""
        first = self.map.request_hr
        rr = self._call(
            f"reading the operator request (HR {first}..{first + REQUEST_REGISTERS - 1})",
            self._read_holding_registers,
            first,
            REQUEST_REGISTERS,
        )
        if len(rr.registers) != REQUEST_REGISTERS:
            raise ProtocolError(f"operator request: {len(rr.registers)} registers in the answer", device=self.device)
        try:
            return decode_request(rr.registers)
        except ValueError as exc:
            raise ProtocolError(f"operator request: {exc}", device=self.device) from None

    def read_status(self) -> PlcStatus:
        rr = self._call(
            f"reading status word (IR {self.map.status_ir})",
            self._read_input_registers,
            self.map.status_ir,
        )
        return PlcStatus.from_word(self._first(rr.registers, "status word"))

    # ------------------------------------------------------------------ plumbing
    def _read_discrete_inputs(self, address: int):
        return self._require_client().read_discrete_inputs(address, count=1, device_id=self.unit_id)

    def _read_input_registers(self, address: int):
        return self._require_client().read_input_registers(address, count=1, device_id=self.unit_id)

    def _read_holding_registers(self, address: int, count: int = 1):
        return self._require_client().read_holding_registers(address, count=count, device_id=self.unit_id)

    def _write_registers(self, address: int, values: list[int]):
        return self._require_client().write_registers(address, values, device_id=self.unit_id)

    def _write_coil(self, address: int, value: bool):
        return self._require_client().write_coil(address, value, device_id=self.unit_id)

    def _write_register(self, address: int, value: int):
        return self._require_client().write_register(address, value, device_id=self.unit_id)

    def _require_client(self) -> ModbusTcpClient:
        if self._client is None:
            raise ConnectionLost("not connected (call connect() first)")  # device added by _call
        return self._client

    def _call(self, action: str, fn, *args):
        """Run one request (under the lock); translate every pymodbus/socket failure into a drivers.errors
        exception."""
        with self._lock:  # the drop of a failed socket too: never under another thread's request
            try:
                rr = fn(*args)
            except ConnectionLost as exc:
                raise ConnectionLost(f"{exc} while {action}", device=self.device) from exc
            except ConnectionException as exc:
                self._drop_socket()
                raise ConnectionLost(f"connection lost while {action}: {exc}", device=self.device) from exc
            except ModbusIOException as exc:
                self._drop_socket()  # a late answer would desynchronise the stream: start clean next call
                if "No response" in str(exc):
                    message = f"no answer within {self.timeout_s} s while {action}"
                    raise DeviceTimeout(message, device=self.device) from exc
                message = f"answer does not match the request while {action}: {exc}"
                raise ProtocolError(message, device=self.device) from exc
            except ModbusException as exc:
                self._drop_socket()
                raise ProtocolError(f"malformed exchange while {action}: {exc}", device=self.device) from exc
            except OSError as exc:  # e.g. ConnectionResetError straight from the socket
                self._drop_socket()
                raise ConnectionLost(f"socket error while {action}: {exc}", device=self.device) from exc
        if rr is None:
            raise ProtocolError(f"no answer object while {action}", device=self.device)
        if rr.isError():
            code = int(getattr(rr, "exception_code", 0))
            name = MODBUS_EXCEPTIONS.get(code, "unknown exception")
            if code in REQUEST_MISMATCH_CODES:
                raise ProtocolError(
                    f"PLC answered Modbus exception 0x{code:02X} {name} while {action} (register map mismatch?)",
                    device=self.device,
                )
            raise DeviceFault(f"PLC refused ({name}) while {action}", code=code, device=self.device)
        return rr

    def _drop_socket(self) -> None:
        if self._client is not None:
            self._client.close()

    def _first(self, values, what: str):
        if not values:
            raise ProtocolError(f"empty {what} in the answer", device=self.device)
        return values[0]
