"""Simulated CANopen hardware of the HAS: COPLEY-like CiA 402 drives and the sensor boards.

The slaves of ``config/canopen/README.md`` on a python-can bus, backed by the plant model of
exo_has_sim, so that the driver can be tested without hardware:

* :mod:`~exo_has_driver.devices.slave`: the CiA 301 services (dictionary from the EDS, NMT,
  heartbeats, SDO server, EMCY);
* :mod:`~exo_has_driver.devices.drive`: the CiA 402 drive in profile velocity mode;
* :mod:`~exo_has_driver.devices.sensor_board`: the sensor board;
* :mod:`~exo_has_driver.devices.rig`: the devices of N joints on one bus with their plants,
  and the fault injection;
* :mod:`~exo_has_driver.devices.main`: the ``can_devices`` process.
"""

from __future__ import annotations

from exo_has_driver.devices.drive import Drive
from exo_has_driver.devices.rig import Joint, Rig
from exo_has_driver.devices.sensor_board import SensorBoard
from exo_has_driver.devices.slave import Slave

__all__ = ['Drive', 'Joint', 'Rig', 'SensorBoard', 'Slave']
