"""Model-error diagnosis (ROS-free): what the simulation gets wrong on measured data, and why.

The record and its windows:

- :mod:`~exo_has_sim.diagnosis.data`: reading and checking a CSV log or a bag;
- :mod:`~exo_has_sim.diagnosis.compare`: windows, the estimation/validation split, fit %;

the plants, models of one actuator over windows of a record, and what they can be extended with:

- :mod:`~exo_has_sim.diagnosis.plants`: a parameter to fit, and the plants' base,
  :class:`~exo_has_sim.diagnosis.plants.WindowedModel`;
- :mod:`~exo_has_sim.diagnosis.effects`: the library of physical effects, which plant has
  which, and their parameters;
- :mod:`~exo_has_sim.diagnosis.has_plant`: the HAS model as a plant, with
  :mod:`~exo_has_sim.diagnosis.has_baseline` (what it fits),
  :mod:`~exo_has_sim.diagnosis.has_drive` (the motor speed and spool the commands make) and
  :mod:`~exo_has_sim.diagnosis.window_loads` (each window's own unmeasured load);
- :mod:`~exo_has_sim.diagnosis.mass_plant`: a generic mass as a plant;
  :mod:`~exo_has_sim.diagnosis.emps`: the EMPS benchmark's record for it;

the methods:

- :mod:`~exo_has_sim.diagnosis.fitting`: parameter fits with confidence intervals;
- :mod:`~exo_has_sim.diagnosis.selection`: scoring, ranking, forward selection of the cause;
- :mod:`~exo_has_sim.diagnosis.limits`: the detection limit of each effect left out;
- :mod:`~exo_has_sim.diagnosis.findings`, :mod:`~exo_has_sim.diagnosis.evidence`,
  :mod:`~exo_has_sim.diagnosis.flow_gains`, :mod:`~exo_has_sim.diagnosis.structure`: whether
  the model's structure describes the record: the findings and the verdict, the record's
  evidence of the circuit and the motor (the flow gain by direction read two ways), the
  fitted model's findings and the other structures fitted;
- :mod:`~exo_has_sim.diagnosis.transfer`: the paper's third-order transfer function;
- :mod:`~exo_has_sim.diagnosis.residuals`: residual tests and the causes' signatures;

and the whole:

- :mod:`~exo_has_sim.diagnosis.loading`: a record to the plant that diagnoses it;
- :mod:`~exo_has_sim.diagnosis.diagnose`: the whole diagnosis, within the time budget of
  :mod:`~exo_has_sim.diagnosis.budget`;
- :mod:`~exo_has_sim.diagnosis.result`: what it found, and the JSON document;
- :mod:`~exo_has_sim.diagnosis.report`: the Markdown report, its plots and the summary;
- :mod:`~exo_has_sim.diagnosis.cli`: ``exo-has diagnose`` (``exo-has-diagnose`` where the
  package was installed by pip, without ROS);

and many records:

- :mod:`~exo_has_sim.diagnosis.records`: the records the inputs hold, their ids, one
  record's diagnosis (the unit of work);
- :mod:`~exo_has_sim.diagnosis.batch`: diagnosing them on local worker processes or a Dask
  cluster, resumably;
- :mod:`~exo_has_sim.diagnosis.summary`: the summary folder, its records' JSON documents,
  summary.md and summary.csv.
"""

from __future__ import annotations

from exo_has_sim.diagnosis.data import Measurement, read_bag, read_csv
from exo_has_sim.diagnosis.diagnose import diagnose
from exo_has_sim.diagnosis.effects import EFFECTS
from exo_has_sim.diagnosis.has_plant import HasPlant
from exo_has_sim.diagnosis.loading import load_plant
from exo_has_sim.diagnosis.mass_plant import MassPlant
from exo_has_sim.diagnosis.plants import WindowedModel
from exo_has_sim.diagnosis.result import Diagnosis

__all__ = ['EFFECTS', 'Diagnosis', 'HasPlant', 'MassPlant', 'Measurement', 'WindowedModel',
           'diagnose', 'load_plant', 'read_bag', 'read_csv']
