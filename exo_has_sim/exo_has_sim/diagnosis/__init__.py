"""Model-error diagnosis (ROS-free): what the simulation gets wrong on measured data, and why.

- :mod:`~exo_has_sim.diagnosis.data`: reading and checking a CSV log or a bag;
- :mod:`~exo_has_sim.diagnosis.plants`: a plant's parameters and the plant over windows;
- :mod:`~exo_has_sim.diagnosis.has_plant`, :mod:`~exo_has_sim.diagnosis.mass_plant`: the HAS
  model and a generic mass as plants;
- :mod:`~exo_has_sim.diagnosis.compare`: windows, the estimation/validation split, fit %;
- :mod:`~exo_has_sim.diagnosis.fitting`: parameter fits with confidence intervals;
- :mod:`~exo_has_sim.diagnosis.effects`: the library of physical effects;
- :mod:`~exo_has_sim.diagnosis.selection`: scoring, ranking, forward selection of the cause;
- :mod:`~exo_has_sim.diagnosis.transfer`: the paper's third-order transfer function;
- :mod:`~exo_has_sim.diagnosis.residuals`: residual tests and the causes' signatures;
- :mod:`~exo_has_sim.diagnosis.diagnose`: the whole diagnosis;
- :mod:`~exo_has_sim.diagnosis.report`: the Markdown report, its plots and the JSON document;
- :mod:`~exo_has_sim.diagnosis.cli`: ``exo-has diagnose``.
"""

from __future__ import annotations

from exo_has_sim.diagnosis.data import Measurement, read_bag, read_csv
from exo_has_sim.diagnosis.diagnose import Diagnosis, diagnose, load_plant
from exo_has_sim.diagnosis.effects import EFFECTS
from exo_has_sim.diagnosis.has_plant import HasPlant
from exo_has_sim.diagnosis.mass_plant import MassPlant

__all__ = ['EFFECTS', 'Diagnosis', 'HasPlant', 'MassPlant', 'Measurement', 'diagnose',
           'load_plant', 'read_bag', 'read_csv']
