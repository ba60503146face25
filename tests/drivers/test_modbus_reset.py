"""A Modbus peer that resets the connection mid-exchange (the PLC stopped): pymodbus lets the
socket's ConnectionResetError through, which the service took for an internal error and
stopped on (seen once in a full run, tests/ops/test_simulated_devices.py); the link says a
connection error, as for a refused connect."""

from __future__ import annotations

from typing import Any

import pytest

from drivers._modbus import ModbusLink
from drivers.errors import DeviceConnectionError


class _Resetting:
    closed = False

    def read_holding_registers(self, *args: Any, **kwargs: Any) -> Any:
        raise ConnectionResetError(104, "Connection reset by peer")

    write_registers = read_holding_registers

    def close(self) -> None:
        self.closed = True


def test_a_reset_by_the_peer_is_a_connection_error() -> None:
    link = ModbusLink("127.0.0.1", 1, unit=1, timeout_s=1.0)
    fake = _Resetting()
    link._client = fake  # type: ignore[assignment]
    with pytest.raises(DeviceConnectionError, match="reset by peer"):
        link.read(0, 2)
    with pytest.raises(DeviceConnectionError, match="reset by peer"):
        link.write(0, [1])
    assert fake.closed
