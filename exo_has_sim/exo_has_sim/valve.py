"""The compact valve's modes, numbered as exo_has_msgs/msg/HasState's ``VALVE_*``."""

from __future__ import annotations

from enum import IntEnum


class ValveMode(IntEnum):
    """Mode of the compact direction/safety valve (Sun et al. 2021, section 2.3.3)."""

    FREE = 0  # motor stopped, no system pressure: both chambers to the tank, the joint is free
    ASSIST = 1  # system pressure established: the pump feeds the cylinder
    RELIEF = 2  # pressure at the safety valve's setting: it relieves to the tank
