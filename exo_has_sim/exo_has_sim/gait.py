"""Normative gait data: loading gait-cycle tables of hip and knee angles.

The shipped table is Winter's normal-cadence adult ensemble average (see data/README.md); any
CSV of the same shape can be loaded: a header row naming the columns ``cycle_percent``,
``hip_angle`` and ``knee_angle`` (degrees, flexion positive), or Winter's layout as shipped.
Optional columns ``hip_moment`` and ``knee_moment`` [N m/kg, extensor positive] are read too
where present (Winter's table has them).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import CubicSpline

from exo_has_sim.errors import ParameterError

DATA_DIR = Path(__file__).resolve().parent / 'data'
WINTER = DATA_DIR / 'winter1991_normal_cadence.csv'

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class GaitCycle:
    """Joint angles over one gait cycle from heel contact.

    Attributes
    ----------
    cycle_percent : np.ndarray
        Gait cycle [%], increasing from 0 to 100.
    hip_angle, knee_angle : np.ndarray
        Flexion angles [rad].
    source : str
        Where the data came from.
    hip_moment, knee_moment : np.ndarray or None
        Net joint moments per body mass [N m/kg], extensor positive (Winter's convention),
        where the table has them.

    """

    cycle_percent: FloatArray
    hip_angle: FloatArray
    knee_angle: FloatArray
    source: str
    hip_moment: FloatArray | None = None
    knee_moment: FloatArray | None = None

    @cached_property
    def _splines(self) -> tuple[CubicSpline, CubicSpline]:
        # 100 % is the next cycle's 0 %: tables often hold both with slightly different values
        # (the mean cycle does not close); drop the 100 % sample and close the cycle on the 0 %
        # value, with a periodic cubic spline, so angles and velocities are continuous.
        keep = self.cycle_percent < 100.0
        cycle = np.append(self.cycle_percent[keep], 100.0)
        hip = np.append(self.hip_angle[keep], self.hip_angle[keep][0])
        knee = np.append(self.knee_angle[keep], self.knee_angle[keep][0])
        return (CubicSpline(cycle, hip, bc_type='periodic'),
                CubicSpline(cycle, knee, bc_type='periodic'))

    def angles_at(self, phase: NDArray[np.float64] | float) -> tuple[FloatArray, FloatArray]:
        """Hip and knee angles [rad] at gait phase(s) in cycles (wrapped to [0, 1))."""
        percent = (np.asarray(phase, dtype=float) % 1.0) * 100.0
        hip, knee = self._splines
        return np.asarray(hip(percent), dtype=float), np.asarray(knee(percent), dtype=float)

    def moments_at(self, phase: NDArray[np.float64] | float) -> tuple[FloatArray, FloatArray]:
        """Hip and knee moments per body mass [N m/kg] at gait phase(s), zero without them.

        Linear between the table's samples, wrapped as :meth:`angles_at`: a moment curve has
        corners (heel strike) that a spline would overshoot.
        """
        percent = (np.asarray(phase, dtype=float) % 1.0) * 100.0
        if self.hip_moment is None or self.knee_moment is None:
            return np.zeros_like(percent), np.zeros_like(percent)
        keep = self.cycle_percent < 100.0  # 100 % is the next cycle's 0 %
        cycle = self.cycle_percent[keep]
        return (np.interp(percent, cycle, self.hip_moment[keep], period=100.0),
                np.interp(percent, cycle, self.knee_moment[keep], period=100.0))


def squat_depth(phase: NDArray[np.float64] | float) -> FloatArray:
    """Share of a squat's depth at phase(s) in cycles: a raised cosine, 0 standing, 1 down.

    No normative squat curve is at hand: hip and knee flex together, with no angular velocity
    at the top and at the bottom.
    """
    return np.asarray(0.5 * (1.0 - np.cos(2.0 * math.pi * np.asarray(phase, dtype=float))),
                      dtype=float)


def load_gait_cycle(path: str | Path = WINTER) -> GaitCycle:
    """Load a gait-cycle table.

    Raises
    ------
    ParameterError
        If the file is missing, has no recognisable columns, non-numeric or non-finite values,
        a cycle that is not increasing over 0 to 100 %, or angles that look like radians.

    """
    source = Path(path)
    try:
        with source.open(encoding='utf-8-sig', newline='') as handle:
            rows = list(csv.reader(handle))
    except OSError as exc:
        msg = f'cannot read gait table {source}: {exc.strerror}'
        raise ParameterError(msg) from exc
    header_index, columns = _find_columns(rows, source)
    cycle_col = columns[0]
    values: list[tuple[float, ...]] = []
    for number, row in enumerate(rows[header_index + 1:], start=header_index + 2):
        cells = [c.strip() for c in row]
        if not any(cells) or len(cells) <= max(columns):
            continue
        if not cells[cycle_col] or not _is_number(cells[cycle_col]):
            continue  # a units row or a trailing note
        try:
            fields = tuple(float(cells[col]) for col in columns)
        except ValueError as exc:
            msg = f'{source}:{number}: not a number: {exc}'
            raise ParameterError(msg) from exc
        if not all(math.isfinite(v) for v in fields):
            msg = f'{source}:{number}: NaN or infinite value'
            raise ParameterError(msg)
        values.append(fields)
    if len(values) < 5:
        msg = f'{source}: fewer than 5 rows of data'
        raise ParameterError(msg)
    data = np.array(values)
    cycle = data[:, 0]
    if np.any(np.diff(cycle) <= 0) or cycle[0] < 0 or cycle[-1] > 100 + 1e-9:
        msg = f'{source}: the gait cycle column must increase within 0 to 100 %'
        raise ParameterError(msg)
    if np.max(np.abs(data[:, 1:3])) < 3.0:
        msg = f'{source}: angles span less than 3 units: they look like radians; give degrees'
        raise ParameterError(msg)
    hip_moment, knee_moment = (data[:, 3], data[:, 4]) if data.shape[1] == 5 else (None, None)
    return GaitCycle(cycle, np.radians(data[:, 1]), np.radians(data[:, 2]), str(source),
                     hip_moment, knee_moment)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _find_columns(rows: list[list[str]], source: Path) -> tuple[int, list[int]]:
    """Return the header row and the columns: cycle, hip, knee (and both moments if present)."""
    aliases = {
        'cycle': ('cycle_percent', '%gait cycle', 'gait_cycle', 'percent'),
        'hip': ('hip_angle', 'hip angle'),
        'knee': ('knee_angle', 'knee angle'),
        'hip_moment': ('hip_moment', 'hip moment'),
        'knee_moment': ('knee_moment', 'knee moment'),
    }
    for index, row in enumerate(rows):
        names = [cell.strip().lower() for cell in row]
        found = {}
        for key, options in aliases.items():
            for col, name in enumerate(names):
                if name in options:
                    found[key] = col
                    break
        if all(key in found for key in ('cycle', 'hip', 'knee')):
            keys = ['cycle', 'hip', 'knee']
            if 'hip_moment' in found and 'knee_moment' in found:
                keys += ['hip_moment', 'knee_moment']
            return index, [found[key] for key in keys]
    msg = (f'{source}: no header row with columns cycle_percent, hip_angle and knee_angle '
           '(degrees)')
    raise ParameterError(msg)
