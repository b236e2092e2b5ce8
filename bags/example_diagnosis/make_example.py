"""Make the worked example: a simulated "measured" session with a hidden effect, and its report.

The session is NOT a recording of real hardware: it is made by the separate truth plant of the
acceptance tests (``test/truth_plant.py``, a HAS written from the paper independently of the
project's model), draw seed 4242 on the hip, walking at 0.85 strides/s for 20 s in closed loop
under its own PD controller at 200 Hz, with the hard-to-know parameters drawn +-30 % around
nominal, sensor noise, and a hidden effect: Coulomb friction of 80 N in the cylinder's seals.
The columns are written as the plant node and controller would publish them, into a rosbag2
bag (MCAP, zstd chunks): ``/left_hip/has_state``, ``/left_hip/has_command`` (each answering a
state 1 ms after it) and ``/joint_reference``; then ``exo-has diagnose`` writes its report.

Run from the repository root: ``.venv/bin/python bags/example_diagnosis/make_example.py``.
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(ROOT / 'test'))

import truth_plant as tp  # noqa: E402
from rigs import rig_file  # noqa: E402

from exo_has_common.bag import BagWriter, default_typestore, ensure_message_type  # noqa: E402
from exo_has_sim.diagnosis.cli import main  # noqa: E402
from exo_has_sim.kinematics import Linkage  # noqa: E402

SEED = 4242
JOINT = 'left_hip'
FRICTION = 80.0  # N
T0_NS = 1_764_000_000_000_000_000


STATE = 'exo_has_msgs/msg/HasState'
COMMAND = 'exo_has_msgs/msg/HasCommand'
JOINTS = 'sensor_msgs/msg/JointState'


def write_bag(draw: tp.Draw, path: Path) -> None:
    """Write a draw's commands, states and references to a rosbag2 MCAP bag at path.

    The messages are serialized with rosbags, not rclpy: rclpy's ``serialize_message``
    (rmw_fastrtps_cpp) leaves CDR's padding bytes uninitialised, so the committed bag would
    change at every run, and makes a JointState with an empty sequence longer than its data,
    which rosbags then refuses to read (test/test_wire.py).
    """
    typestore = default_typestore()
    for msgtype in (STATE, COMMAND, JOINTS):
        ensure_message_type(msgtype, typestore)
    types = typestore.types

    def header(ns: int) -> object:
        sec, nanosec = divmod(ns, 1_000_000_000)
        return types['std_msgs/msg/Header'](
            stamp=types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec), frame_id='')

    def cdr(message: object, msgtype: str) -> bytes:
        return bytes(typestore.serialize_cdr(message, msgtype))

    linkage = Linkage.from_parameters(tp.nominal_parameters('hip'))
    c = draw.columns
    angles = np.asarray(linkage.angle(c['reference']), dtype=float)
    period_ns = round(draw.period * 1e9)
    none = np.zeros(0)
    with BagWriter(path, compress=True) as writer:
        writer.add_topic(f'/{JOINT}/has_state', STATE)
        writer.add_topic(f'/{JOINT}/has_command', COMMAND)
        writer.add_topic('/joint_reference', JOINTS)
        for k in range(len(c['time'])):
            t = T0_NS + k * period_ns
            reference = types[JOINTS](header=header(t), name=[JOINT],
                                      position=np.array([angles[k]]), velocity=none,
                                      effort=none)
            writer.write('/joint_reference', t, cdr(reference, JOINTS))
            state = types[STATE](header=header(t), joint=JOINT,
                                 position=float(c['position'][k]), velocity=math.nan,
                                 pressure_a=float(c['pressure_a'][k]),
                                 pressure_b=float(c['pressure_b'][k]),
                                 motor_speed=float(c['motor_speed'][k]),
                                 motor_speed_command=float(c['motor_speed_command'][k - 1])
                                 if k else 0.0, motor_current=math.nan,
                                 load_force=float(c['load_force'][k]), valve_mode=1)
            writer.write(f'/{JOINT}/has_state', t, cdr(state, STATE))
            command = types[COMMAND](header=header(t + 1_000_000), joint=JOINT,
                                     motor_speed=float(c['motor_speed_command'][k]),
                                     enable=True)
            writer.write(f'/{JOINT}/has_command', t + 1_000_000, cdr(command, COMMAND))


def make() -> int:
    """Make the example's bag, its diagnosis report and JSON; return the exit code."""
    os.chdir(ROOT)  # the report names the bag by its path from the repository root
    here = HERE.relative_to(ROOT)
    draw = tp.draw(SEED, 'hip', effect='coulomb_friction', size=FRICTION, excitation='walk')
    bag = here / 'bag'
    if bag.exists():
        for file in bag.iterdir():
            file.unlink()
        bag.rmdir()
    write_bag(draw, bag)
    truth = {'effect': draw.effect, 'size': draw.size, 'parameters': draw.parameters,
             'noise': draw.noise, 'load_mass': draw.load_mass}
    (here / 'truth.txt').write_text(
        'Hidden in the session (not read by the diagnosis):\n'
        + '\n'.join(f'{k}: {v}' for k, v in truth.items()) + '\n', encoding='utf-8')
    return main([str(bag), '--joint', JOINT, '--params', str(rig_file('hip')),
                 '--load-mass', str(draw.load_mass), '--report',
                 str(here / 'report'), '--json', str(here / 'diagnosis.json')])


if __name__ == '__main__':
    sys.exit(make())
