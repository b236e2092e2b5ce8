"""One simulated HAS joint as the plant node sees it: commands and loads in, samples out.

ROS-free: the node converts messages to these calls. The drive follows the newest command
(as a speed-controlled drive does) until another arrives; before the first command it holds the
motor speed of the initial state, which keeps the load at rest in assist, as if the drive had
been holding the joint when the simulation started. A disabled drive (``enable`` false) stops
the motor, and the compact valve falls to free mode.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from exo_has_sim import model
from exo_has_sim.errors import ParameterError, SimulationError
from exo_has_sim.kinematics import Linkage
from exo_has_sim.loads import default_load_force
from exo_has_sim.parameters import HasParameters, load_parameters
from exo_has_sim.plant_simulator import PlantSimulator

#: Longest span one call integrates [s]; a longer gap (a stalled process) is integrated in
#: pieces of this length so that the adaptive solver's step history stays meaningful.
MAX_SPAN = 0.05


@dataclass(frozen=True)
class PlantSample:
    """The state of one HAS at an instant, in the units of exo_has_msgs/msg/HasState."""

    position: float  # m
    velocity: float  # m/s
    pressure_a: float  # Pa, gauge
    pressure_b: float  # Pa, gauge (the rod chamber is open to the tank)
    motor_speed: float  # rad/s
    motor_speed_command: float  # rad/s
    load_force: float  # N
    valve_mode: int  # exo_has_msgs/msg/HasState VALVE_*


class Plant:
    """A single HAS joint advanced by elapsed time under the newest command and load.

    Parameters
    ----------
    joint : str
        Joint name (used to check incoming commands).
    params : str or Path or HasParameters
        ``'hip'``, ``'knee'``, a parameters file, or a parameter set.
    initial_angle : float
        Joint angle at the start [rad], flexion positive.
    load_force : float or None
        External rod force [N]; None for :func:`exo_has_sim.loads.default_load_force`.

    Raises
    ------
    ParameterError, KinematicsError
        For bad parameters or an initial angle outside the linkage's range.

    """

    def __init__(self, joint: str, params: str | Path | HasParameters,
                 initial_angle: float = 0.0, load_force: float | None = None) -> None:
        self.joint = joint
        self.params = params if isinstance(params, HasParameters) else load_parameters(params)
        if not math.isfinite(initial_angle):
            msg = f'initial_angle must be finite [rad], got {initial_angle!r}'
            raise ParameterError(msg)
        self.linkage = Linkage.from_parameters(self.params)
        self.default_load = default_load_force(self.params, standing_angle=initial_angle)
        self.load = self.default_load if load_force is None else float(load_force)
        position = float(self.linkage.position(initial_angle))
        y0 = model.initial_state(self.params, position, self.load)
        self._simulator = PlantSimulator([self.params], y0[None, :])
        self._command = float(y0[model.N])

    def warm_up(self) -> None:
        """Run the compiled model once on a copy, so the first real step is not slow."""
        scratch = PlantSimulator([self.params], self._simulator.state.copy())
        scratch.step(np.array([self._command]), np.array([self.load]), 1e-3)

    def set_load(self, load_force: float) -> None:
        """Set the external rod force [N], positive pushing the cylinder in.

        Raises
        ------
        SimulationError
            For a non-finite value.

        """
        if not math.isfinite(load_force):
            msg = f'load force must be finite [N], got {load_force!r}'
            raise SimulationError(msg)
        self.load = float(load_force)

    def command(self, joint: str, motor_speed: float, enable: bool) -> str | None:
        """Take a command; return why it was refused, or None.

        A command for another joint is refused; a non-finite speed stops the motor (as a
        disabled drive) and is reported, so that garbage never moves the joint.
        """
        if joint and joint != self.joint:
            return f'ignored a command for joint {joint!r} on the {self.joint} plant'
        if not math.isfinite(motor_speed):
            self._command = 0.0
            return f'non-finite motor speed command {motor_speed!r} rad/s: motor stopped'
        self._command = float(motor_speed) if enable else 0.0
        return None

    def advance(self, elapsed: float) -> PlantSample:
        """Integrate ``elapsed`` seconds under the held command and load; return the sample.

        Raises
        ------
        SimulationError
            If elapsed is not positive or the integration diverges.

        """
        if not (math.isfinite(elapsed) and elapsed > 0.0):
            msg = f'elapsed time must be positive and finite [s], got {elapsed!r}'
            raise SimulationError(msg)
        commands = np.array([self._command])
        loads = np.array([self.load])
        remaining = elapsed
        while remaining > 0.0:
            span = min(remaining, MAX_SPAN)
            self._simulator.step(commands, loads, span)
            remaining -= span
        return self.sample()

    def sample(self) -> PlantSample:
        """Return the current state."""
        y = self._simulator.state[0]
        return PlantSample(
            position=float(y[model.X]), velocity=float(y[model.V]),
            pressure_a=float(y[model.PA]), pressure_b=0.0, motor_speed=float(y[model.N]),
            motor_speed_command=self._command, load_force=self.load,
            valve_mode=self._simulator.valve_modes()[0])

    @property
    def time(self) -> float:
        """Simulated time since the start [s]."""
        return self._simulator.time
