"""The PD gains as node parameters: declared per joint type, changed at run time when safe.

With them each joint type's parameter set, ``<type>.params`` (:func:`declare_parameter_set`),
whose linkage and motor limit the gains are judged on.

One source for every node that runs the PD law: the PD controller node (the simulation's and
the old chain's) and the robot loop's bridge (issue 28). A joint type's gains are the
parameters ``<type>.kp``, ``<type>.kd``, ``<type>.kff`` and ``<type>.motor_speed_limit``
(``hip.kp``, ...). A set, at start or by ``ros2 param set``, is judged by
:func:`exo_has_control.pd.unsafe_gains` at the node's control period (the sampled loop on the
linearised HAS must stay damped, the limit within the motor's top speed) and refused with the
reason where unsafe.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace

from rclpy.node import Node
from rclpy.parameter import Parameter

from exo_has_control.pd import PAPER_KD, PAPER_KP, PdGains, unsafe_gains
from exo_has_runtime.node_parameters import declare
from exo_has_sim.parameters import HasParameters, load_parameters

#: Bounds of every gain and of the motor speed limit (in their units).
GAIN_RANGE = (0.0, 1.0e7)
#: The parameters of a joint type's gains (``hip.kp``, ...) and the PdGains field of each.
GAIN_FIELDS = {'kp': 'kp', 'kd': 'kd', 'kff': 'kff', 'motor_speed_limit': 'speed_limit'}


def declare_parameter_set(node: Node, kind: str) -> HasParameters:
    """Declare and load a joint type's parameter set, ``<kind>.params`` (``hip``, ``knee``)."""
    return load_parameters(declare(
        node, f'{kind}.params', kind,
        f'{kind} HAS parameter set (linkage, motor limit): {kind} or a parameters YAML file'))


def declare_gains(node: Node, params: HasParameters, period: float) -> PdGains:
    """Declare and read a joint type's gains (changeable at run time); refuse unsafe ones.

    Parameters
    ----------
    node : Node
        The node that declares them.
    params : HasParameters
        The joint type's parameter set: its linkage and motor limit.
    period : float
        Control period [s] at which the gains are judged.

    Raises
    ------
    ValueError
        If the gains are out of range or unsafe at ``period``; the message names the joint type
        and the reason.

    """
    kind = params.joint_type
    paper = PdGains.paper(params)
    specs = (
        ('kp', PAPER_KP, "position gain [(rad/s)/m]: the paper's P = 35 read as (rad/s) per mm"),
        ('kd', PAPER_KD, "velocity-error gain [(rad/s)/(m/s)]: the paper's D = 15"),
        ('kff', paper.kff, 'velocity feedforward [(rad/s)/(m/s)]: 1/K of Eq. 14 with A_A; '
                           "0 gives the paper's pure PD"),
        ('motor_speed_limit', params.motor_speed_max,
         'motor speed saturation [rad/s] (the paper: 4000 r/min)'),
    )
    values = {GAIN_FIELDS[key]: declare(node, f'{kind}.{key}', float(default), description,
                                        GAIN_RANGE, read_only=False)
              for key, default, description in specs}
    try:
        gains = PdGains(**values)
    except ValueError as exc:
        msg = f'{kind} gains: {exc}'
        raise ValueError(msg) from None
    problem = unsafe_gains(params, gains, period)
    if problem:
        msg = f'{kind} gains: {problem}'
        raise ValueError(msg)
    return gains


def gain_changes(parameters: Sequence[Parameter], gains: Mapping[str, PdGains],
                 params: Mapping[str, HasParameters],
                 period: float) -> tuple[dict[str, PdGains], str]:
    """Judge a set of parameters: the new gains of each joint type it changes, or the refusal.

    Parameters
    ----------
    parameters : Sequence[Parameter]
        What ``ros2 param set`` (or a set of several) asks; parameters other than gains are
        passed over.
    gains, params : Mapping[str, PdGains], Mapping[str, HasParameters]
        The current gains and the parameter set of each joint type the node runs.
    period : float
        Control period [s] at which the gains are judged.

    Returns
    -------
    accepted : dict[str, PdGains]
        The new gains by joint type (empty where refused or where no gain changed).
    reason : str
        Why the whole set is refused ('' where it is accepted): the joint type and the problem.

    """
    changes: dict[str, dict[str, float]] = {}
    for parameter in parameters:
        kind, _, key = parameter.name.partition('.')
        if kind in gains and key in GAIN_FIELDS:
            changes.setdefault(kind, {})[GAIN_FIELDS[key]] = float(parameter.value)
    accepted: dict[str, PdGains] = {}
    for kind, values in changes.items():
        try:
            changed = replace(gains[kind], **values)
        except ValueError as exc:
            return {}, f'{kind} gains: {exc}'
        problem = unsafe_gains(params[kind], changed, period)
        if problem:
            return {}, f'{kind} gains: {problem}'
        accepted[kind] = changed
    return accepted, ''
