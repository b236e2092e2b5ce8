"""The EMPS benchmark shipped with the package: real data for the generic mass plant.

EMPS (Electro-Mechanical Positioning System, Janot, Gautier and Brunot 2019, on
nonlinearbenchmark.org) is a prismatic joint driven by a DC motor and a ball screw, measured at
1 kHz in closed loop: motor voltage ``vir`` [V] (force = ``gtau`` vir, gtau = 35.15 N/V),
position ``qm`` [m] and its reference ``qg`` [m]. Its description gives the model
``M q'' + F_v q' + F_c sign(q') + offset = force`` and the reference values below (identified
by the inverse-model least squares the benchmark documents). ``data/emps/`` holds the
estimation record (``DATA_EMPS.mat``) unchanged; its README says where it comes from.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from exo_has_sim.diagnosis.data import Measurement, check_columns

DATA_FILE = Path(__file__).resolve().parent.parent / 'data' / 'emps' / 'emps_estimation.npz'
#: The benchmark's reference values: M [kg], F_v [N s/m], F_c [N], offset [N].
REFERENCE = {'mass': 95.1089, 'viscous_friction': 203.5034, 'coulomb_friction': 20.3935,
             'offset': -3.1648}


def load_emps(path: str | Path = DATA_FILE) -> Measurement:
    """Return the EMPS estimation record as a mass-plant measurement."""
    with np.load(path) as data:
        columns = {'time': data['t'], 'force': float(data['gtau'][0]) * data['vir'],
                   'position': data['qm'], 'reference': data['qg']}
    return check_columns(columns, 'mass', f'EMPS benchmark ({Path(path).name})')
