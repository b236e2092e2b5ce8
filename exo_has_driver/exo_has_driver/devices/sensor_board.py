"""The simulated HAS sensor board: cylinder position, chamber pressures and velocity on SYNC.

On every SYNC (in pre-operational too, so that SDO reads see fresh values) the board samples
its plant and increments its sample counter; in NMT operational it then sends TPDO1
(position [um], pressure A and B [kPa]) and TPDO2 (velocity [um/s], status bits, counter).
Values saturate at their type's range, one above the most negative value, which is the
no-reading sentinel (``can_dictionary.NO_READING_*``) sent with the channel's status bit for
a non-finite reading. The velocity is the plant's cylinder velocity (the real board's filtered
derivative is not modelled: it would only add the filter's lag).

Fault injection: :meth:`SensorBoard.override` replaces a channel's reading with a value in
SI units (position [m], pressures [Pa], velocity [m/s]; NaN for "no reading") until cleared.

Master heartbeat loss (1016h): the board sends EMCY 8130h (error register bit 4, comms) and
keeps sampling and sending: a sensor has nothing to make safe, and its data keep flowing to
a master that recovers; when the master's heartbeat returns it sends EMCY 0000h (error reset).
"""

from __future__ import annotations

import math
from pathlib import Path

from exo_has_driver import can_dictionary as cd
from exo_has_driver.devices.slave import EDS_DIR, Send, Slave, Value, error_register_for
from exo_has_driver.errors import FaultInjectionError
from exo_has_sim.plant import Plant, PlantSample

#: EDS of the sensor board.
SENSOR_BOARD_EDS = EDS_DIR / 'has_sensor_board.eds'

#: Channels a reading can be overridden on, with their status bit.
CHANNELS = {'position': cd.SENSOR_FAULT_POSITION, 'pressure_a': cd.SENSOR_FAULT_PRESSURE_A,
            'pressure_b': cd.SENSOR_FAULT_PRESSURE_B, 'velocity': cd.SENSOR_FAULT_VELOCITY}

_I32_LOW, _I32_HIGH = cd.NO_READING_I32 + 1, 0x7FFFFFFF
_I16_LOW, _I16_HIGH = cd.NO_READING_I16 + 1, 0x7FFF


def encode_reading(value: float, unit: float, low: int, high: int, sentinel: int) -> int:
    """Raw value of a reading in SI units: rounded, saturated to [low, high]; NaN: sentinel."""
    if math.isnan(value):
        return sentinel
    raw = value / unit
    if raw >= high:
        return high
    if raw <= low:
        return low
    return round(raw)


class SensorBoard(Slave):
    """The sensor board of one joint; see the module docstring.

    Parameters
    ----------
    node_id : int
        CANopen node ID.
    plant : Plant
        The joint the sensors sit on.
    send : callable
        ``send(cob_id, data)``.
    eds : Path
        The board's EDS file.

    """

    kind = 'sensor board'

    def __init__(self, node_id: int, plant: Plant, send: Send,
                 eds: Path = SENSOR_BOARD_EDS) -> None:
        super().__init__(node_id, eds, send)
        self.plant = plant
        self.overrides: dict[str, float] = {}
        self._tpdo1_ok = True
        self._tpdo2_ok = True

    def override(self, channel: str, value: float | None) -> None:
        """Report ``value`` (SI units; NaN: no reading) on ``channel``; None: the plant again.

        Raises
        ------
        FaultInjectionError
            For an unknown channel or an infinite value.

        """
        if channel not in CHANNELS:
            msg = f'unknown sensor channel {channel!r}: expected one of {", ".join(CHANNELS)}'
            raise FaultInjectionError(msg)
        if value is None:
            self.overrides.pop(channel, None)
            return
        if math.isinf(value):
            msg = f'a sensor reading must be finite or NaN, got {value!r}'
            raise FaultInjectionError(msg)
        self.overrides[channel] = float(value)

    # --- application hooks -------------------------------------------------------------------
    def _reset_application(self) -> None:
        self._update_flags()
        self._sample(self.plant.sample())

    def _check_write(self, index: int, subindex: int, value: Value) -> None:
        super()._check_write(index, subindex, value)
        self._check_pdo_write(index, subindex, value,
                              {cd.TPDO1_MAPPING: cd.SENSOR_TPDO1_MAP,
                               cd.TPDO2_MAPPING: cd.SENSOR_TPDO2_MAP},
                              {cd.TPDO1_COMMUNICATION: cd.TPDO1_BASE + self.node_id,
                               cd.TPDO2_COMMUNICATION: cd.TPDO2_BASE + self.node_id})

    def _written(self, index: int, subindex: int, value: Value) -> None:
        if index in (cd.TPDO1_COMMUNICATION, cd.TPDO2_COMMUNICATION, cd.TPDO1_MAPPING,
                     cd.TPDO2_MAPPING):
            self._update_flags()

    def _refresh(self, index: int) -> None:
        if index in (cd.SENSOR_VALUES, cd.SENSOR_STATUS):
            self._sample(self.plant.sample())

    def _heartbeat_lost(self) -> None:
        self.values[(cd.ERROR_REGISTER, 0)] = error_register_for(cd.ERROR_HEARTBEAT_LOST)
        self.send_emcy(cd.ERROR_HEARTBEAT_LOST)

    def _heartbeat_back(self) -> None:
        self.values[(cd.ERROR_REGISTER, 0)] = 0
        self.send_emcy(0x0000)

    def _update_flags(self) -> None:
        self._tpdo1_ok = self.pdo_enabled(cd.TPDO1_COMMUNICATION, cd.TPDO1_MAPPING)
        self._tpdo2_ok = self.pdo_enabled(cd.TPDO2_COMMUNICATION, cd.TPDO2_MAPPING)

    # --- sampling ------------------------------------------------------------------------------
    def _sample(self, sample: PlantSample) -> tuple[int, int, int, int, int]:
        overrides = self.overrides
        position = overrides.get('position', sample.position)
        pressure_a = overrides.get('pressure_a', sample.pressure_a)
        pressure_b = overrides.get('pressure_b', sample.pressure_b)
        velocity = overrides.get('velocity', sample.velocity)
        status = 0
        for channel, reading in (('position', position), ('pressure_a', pressure_a),
                                 ('pressure_b', pressure_b), ('velocity', velocity)):
            if math.isnan(reading):
                status |= CHANNELS[channel]
        raw = (encode_reading(position, cd.POSITION_UNIT, _I32_LOW, _I32_HIGH,
                              cd.NO_READING_I32),
               encode_reading(pressure_a, cd.PRESSURE_UNIT, _I16_LOW, _I16_HIGH,
                              cd.NO_READING_I16),
               encode_reading(pressure_b, cd.PRESSURE_UNIT, _I16_LOW, _I16_HIGH,
                              cd.NO_READING_I16),
               encode_reading(velocity, cd.VELOCITY_SENSOR_UNIT, _I32_LOW, _I32_HIGH,
                              cd.NO_READING_I32),
               status)
        values = self.values
        for sub in range(4):
            values[(cd.SENSOR_VALUES, sub + 1)] = raw[sub]
        values[(cd.SENSOR_STATUS, 0)] = status
        return raw

    def on_sync(self, sample: PlantSample) -> None:
        """Sample ``sample`` (the plant at this SYNC), count, and send both TPDOs."""
        position, pressure_a, pressure_b, velocity, status = self._sample(sample)
        counter = (self.get(cd.SENSOR_COUNTER) + 1) & 0xFFFF
        self.values[(cd.SENSOR_COUNTER, 0)] = counter
        if self.pdo_active:
            if self._tpdo1_ok:
                self.send(cd.TPDO1_BASE + self.node_id,
                          cd.SENSOR_TPDO1.pack(position, pressure_a, pressure_b))
            if self._tpdo2_ok:
                self.send(cd.TPDO2_BASE + self.node_id,
                          cd.SENSOR_TPDO2.pack(velocity, status, counter))
