"""The PD law of a HAS position loop, written once for the controller and the simulators.

A plain function of floats with no imports: the controller node calls it as it is (and so reads
it without loading the simulator), the fast simulator compiles it into its closed loop with
numba, and the solve_ivp reference calls it between two integrations.
"""

from __future__ import annotations


def pd_speed_command(kp: float, kd: float, kff: float, speed_limit: float, x_ref: float,
                     v_ref: float, x: float, v: float) -> float:
    """Return the motor speed command [rad/s] of the sampled PD law with velocity feedforward.

    ``kff v_ref + kp (x_ref - x) + kd (v_ref - v)``, saturated at +/- ``speed_limit``.

    Parameters
    ----------
    kp : float
        Position gain [(rad/s) per m].
    kd : float
        Velocity-error gain [(rad/s) per (m/s)].
    kff : float
        Velocity feedforward [(rad/s) per (m/s)].
    speed_limit : float
        Motor speed saturation [rad/s].
    x_ref, v_ref : float
        Reference cylinder position [m] and velocity [m/s].
    x, v : float
        Measured position [m] and velocity [m/s].

    """
    command = kff * v_ref + kp * (x_ref - x) + kd * (v_ref - v)
    return min(max(command, -speed_limit), speed_limit)
