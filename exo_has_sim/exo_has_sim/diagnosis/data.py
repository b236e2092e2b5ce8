"""Measured data for a diagnosis: reading a CSV log or a bag, and checking it.

A measurement is one actuator's signals on one time base, SI units throughout. The CSV layout
has a header row and one row per sample:

- ``time`` [s], strictly increasing;
- the input: ``motor_speed_command`` [rad/s] for a HAS (positive pumps oil into the rodless
  chamber and extends the cylinder), or ``force`` [N] for the generic mass plant;
- ``position`` [m], the cylinder's extension from its retracted end;
- optionally ``reference`` [m], ``pressure_a`` and ``pressure_b`` [Pa, gauge],
  ``motor_speed`` [rad/s] and ``load_force`` [N, positive pushing the cylinder in].

The input at row k is the one sent at ``time[k]`` and held until the next row (zero-order hold),
as a controller running at the sample rate sends it.

The checks name what is wrong and where: the missing columns, the row of the first time that
does not increase, the place of the first run of NaN (an optional column that is NaN
throughout counts as not measured, as HasState's NaN fields), and values whose size betrays a
unit mistake (a position beyond the stroke in millimetres, a motor speed beyond the motor's top
speed in r/min, a pressure that is too small to be in pascal). Slightly irregular sampling (a
bag's message stamps) is resampled onto a uniform grid at the median period, linearly for the
measured signals, and for the input, held from each stamp to the next, as its mean over each
grid period (:func:`held_mean`); gaps of more than :data:`MAX_GAP_PERIODS` periods are
refused.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from exo_has_sim.errors import MeasurementError

FloatArray = NDArray[np.float64]

#: Input column of each plant.
INPUT_COLUMNS = {'has': 'motor_speed_command', 'mass': 'force'}
#: Optional columns (SI units) the diagnosis uses when present.
OPTIONAL_COLUMNS = ('reference', 'pressure_a', 'pressure_b', 'motor_speed', 'load_force')
#: Fewest samples a diagnosis can split into estimation and validation windows.
MIN_SAMPLES = 200
#: Largest gap in the time stamps, in median sample periods, that resampling bridges.
MAX_GAP_PERIODS = 5.0
#: Relative spread of the sample periods below which the time base counts as uniform.
UNIFORM_TOLERANCE = 1e-3
RPM = 2.0 * math.pi / 60.0  # rad/s per r/min


@dataclass(frozen=True)
class Measurement:
    """One actuator's measured signals on a uniform time base.

    Attributes
    ----------
    time : FloatArray
        Sample times [s], uniform, shape (K,).
    input : FloatArray
        Input held from each sample to the next: motor speed command [rad/s] (HAS) or force
        [N] (mass plant), shape (K,).
    position : FloatArray
        Measured position [m], shape (K,).
    optional : Mapping[str, FloatArray]
        The optional columns that were measured (names of :data:`OPTIONAL_COLUMNS`).
    plant : str
        ``'has'`` or ``'mass'``.
    source : str
        Where the data came from (file, bag and joint).
    notes : tuple[str, ...]
        What loading did to the data (resampling, columns dropped as not measured).

    """

    time: FloatArray
    input: FloatArray
    position: FloatArray
    optional: Mapping[str, FloatArray] = field(default_factory=dict)
    plant: str = 'has'
    source: str = ''
    notes: tuple[str, ...] = ()

    @property
    def period(self) -> float:
        """Sample period [s]."""
        return float(self.time[1] - self.time[0])

    @property
    def samples(self) -> int:
        """Number of samples K."""
        return int(self.time.shape[0])

    @property
    def duration(self) -> float:
        """Time spanned [s]."""
        return float(self.time[-1] - self.time[0])

    @property
    def input_name(self) -> str:
        """Column name of the input."""
        return INPUT_COLUMNS[self.plant]

    def has(self, name: str) -> bool:
        """Whether an optional signal was measured."""
        return name in self.optional

    def signal(self, name: str) -> FloatArray:
        """Return a signal by column name (``position``, the input's, or an optional one)."""
        if name == 'position':
            return self.position
        if name == self.input_name:
            return self.input
        try:
            return self.optional[name]
        except KeyError:
            msg = f'{self.source}: {name} was not measured'
            raise MeasurementError(msg) from None

    def slice(self, start: int, stop: int) -> Measurement:
        """Return the samples start:stop as a measurement of their own."""
        return Measurement(self.time[start:stop], self.input[start:stop],
                           self.position[start:stop],
                           {k: v[start:stop] for k, v in self.optional.items()}, self.plant,
                           self.source, self.notes)


@dataclass(frozen=True)
class Limits:
    """Plausible sizes of the signals, to tell a unit mistake (values from the parameters).

    Attributes
    ----------
    stroke : float or None
        Largest position [m]; None for no check.
    motor_speed_max : float or None
        The motor's top speed [rad/s]; None for no check.

    """

    stroke: float | None = None
    motor_speed_max: float | None = None


def _nan_runs(values: FloatArray) -> list[tuple[int, int]]:
    """Index ranges [start, stop) of the runs of NaN."""
    bad = np.isnan(values).astype(np.int8)
    edges = np.diff(np.concatenate(([0], bad, [0])))
    starts = np.flatnonzero(edges == 1)
    stops = np.flatnonzero(edges == -1)
    return list(zip(starts.tolist(), stops.tolist(), strict=True))


def check_columns(columns: Mapping[str, FloatArray], plant: str, source: str,
                  limits: Limits = Limits(), first_row: int = 2) -> Measurement:
    """Check raw columns and build a :class:`Measurement` on a uniform time base.

    Parameters
    ----------
    columns : Mapping[str, FloatArray]
        Signals by CSV column name, equal lengths; unknown names are ignored.
    plant : str
        ``'has'`` or ``'mass'``.
    source : str
        Name of the data's origin for the messages.
    limits : Limits
        Sizes beyond which a value betrays a unit mistake.
    first_row : int
        Row number (1-based, in the file) of the first sample, for the messages.

    Raises
    ------
    MeasurementError
        Naming the missing columns, the first non-increasing time, the first NaN run, a
        likely unit mistake, too short a record, or too large a gap.

    """
    if plant not in INPUT_COLUMNS:
        msg = f'unknown plant {plant!r}: expected one of {", ".join(INPUT_COLUMNS)}'
        raise MeasurementError(msg)
    required = ('time', INPUT_COLUMNS[plant], 'position')
    missing = [name for name in required if name not in columns]
    if missing:
        found = ', '.join(columns) or 'none'
        msg = (f'{source}: missing column {", ".join(missing)} (required: '
               f'{", ".join(required)}; found: {found})')
        raise MeasurementError(msg)
    data = {name: np.asarray(values, dtype=float) for name, values in columns.items()
            if name in (*required, *OPTIONAL_COLUMNS)}
    lengths = {len(v) for v in data.values()}
    if len(lengths) != 1:
        msg = f'{source}: columns of unequal length {sorted(lengths)}'
        raise MeasurementError(msg)
    count = lengths.pop()
    if count < MIN_SAMPLES:
        msg = f'{source}: {count} samples; a diagnosis needs at least {MIN_SAMPLES}'
        raise MeasurementError(msg)
    notes: list[str] = []
    for name in [n for n in OPTIONAL_COLUMNS if n in data]:
        if np.all(np.isnan(data[name])):
            del data[name]
            notes.append(f'{name} is NaN throughout: taken as not measured')
    for name, values in data.items():
        runs = _nan_runs(values)
        if runs:
            start, stop = runs[0]
            where = (f'rows {start + first_row} to {stop - 1 + first_row}' if stop - start > 1
                     else f'row {start + first_row}')
            t = data['time']
            when = '' if name == 'time' or np.isnan(t[start]) else f' (t = {t[start]:.4g} s)'
            msg = (f'{source}: {name} is NaN in {where}{when}, {stop - start} samples'
                   f'{f"; {len(runs)} NaN runs in all" if len(runs) > 1 else ""}; '
                   'cut the record or fill the gap')
            raise MeasurementError(msg)
        if not np.all(np.isfinite(values)):
            row = int(np.flatnonzero(~np.isfinite(values))[0])
            msg = f'{source}: {name} is infinite in row {row + first_row}'
            raise MeasurementError(msg)
    time = data['time']
    steps = np.diff(time)
    if np.any(steps <= 0.0):
        row = int(np.flatnonzero(steps <= 0.0)[0]) + 1
        msg = (f'{source}: time does not increase at row {row + first_row} '
               f'({time[row - 1]!r} s, then {time[row]!r} s); sort the rows or drop '
               'the repeated samples')
        raise MeasurementError(msg)
    period = float(np.median(steps))
    if period >= 0.5:
        msg = (f'{source}: median sample period {period:g} s; time looks like milliseconds '
               '(seconds expected)')
        raise MeasurementError(msg)
    _check_units(data, plant, source, limits)
    if np.max(np.abs(steps - period)) > UNIFORM_TOLERANCE * period:
        largest = float(np.max(steps))
        if largest > MAX_GAP_PERIODS * period:
            row = int(np.argmax(steps)) + 1
            msg = (f'{source}: a gap of {largest:.4g} s ({largest / period:.1f} sample periods) '
                   f'before row {row + first_row} (t = {time[row]:.4g} s); split the record '
                   'there')
            raise MeasurementError(msg)
        data = _resample(data, period, INPUT_COLUMNS[plant])
        notes.append(f'irregular stamps (periods {np.min(steps) * 1e3:.3g} to '
                     f'{largest * 1e3:.3g} ms) resampled at {period * 1e3:.4g} ms')
    else:
        # Exactly uniform in effect: rebuild the grid so that period is exact.
        data['time'] = time[0] + np.arange(count) * float((time[-1] - time[0]) / (count - 1))
    optional = {name: data[name] for name in OPTIONAL_COLUMNS if name in data}
    return Measurement(data['time'], data[INPUT_COLUMNS[plant]], data['position'], optional,
                       plant, source, tuple(notes))


def _check_units(data: Mapping[str, FloatArray], plant: str, source: str,
                 limits: Limits) -> None:
    position = data['position']
    if limits.stroke is not None:
        largest = float(np.max(np.abs(position)))
        if largest > 1.5 * limits.stroke:
            unit = 'millimetres' if largest / 1000.0 <= 1.5 * limits.stroke else 'not metres'
            msg = (f'{source}: position looks like {unit} (max {largest:.4g} > stroke '
                   f'{limits.stroke:g} m); positions are in metres from the retracted end')
            raise MeasurementError(msg)
    speed_columns = ('motor_speed_command', 'motor_speed') if plant == 'has' else ()
    for name in speed_columns:
        if name in data and limits.motor_speed_max is not None:
            largest = float(np.max(np.abs(data[name])))
            if largest > 1.5 * limits.motor_speed_max:
                msg = (f'{source}: {name} looks like r/min (max |{name}| {largest:.4g} > '
                       f"{limits.motor_speed_max:.4g} rad/s, the motor's top speed; "
                       f'{largest:.4g} r/min would be {largest * RPM:.4g} rad/s); '
                       'speeds are in rad/s')
                raise MeasurementError(msg)
    for name in ('pressure_a', 'pressure_b'):
        if name in data:
            largest = float(np.max(np.abs(data[name])))
            # A transducer read in pascal moves by more than 1 kPa in noise alone, even on a
            # rod side at the tank; a column that never reaches it is in MPa or bar.
            if 0.0 < largest < 1000.0:
                msg = (f'{source}: {name} looks like MPa or bar (max {largest:.4g}, under '
                       "1 kPa, below any pressure transducer's noise in pascal); pressures "
                       'are gauge pascal')
                raise MeasurementError(msg)
            if largest > 1e9:
                msg = f'{source}: {name} reaches {largest:.4g}, beyond any HAS in pascal'
                raise MeasurementError(msg)


def _resample(data: Mapping[str, FloatArray], period: float,
              input_name: str) -> dict[str, FloatArray]:
    time = data['time']
    count = math.floor((time[-1] - time[0]) / period + 1e-9) + 1
    grid = time[0] + np.arange(count) * period
    out: dict[str, FloatArray] = {'time': grid}
    for name, values in data.items():
        if name == 'time':
            continue
        if name == input_name:
            out[name] = held_mean(time, values, grid, period)
        else:
            out[name] = np.interp(grid, time, values)
    return out


def held_mean(time: FloatArray, values: FloatArray, grid: FloatArray,
              period: float) -> FloatArray:
    """Mean over each grid period of a signal held from each of its stamps to the next.

    What a plant received over ``[grid[j], grid[j] + period)``: taking the value held at the
    grid instant instead shifted an input by a whole period wherever its stamp fell just after
    the instant, as half the stamps of a plant node's jittering ticks do (the nominal model's
    validated position fit on a demo's bag was 98.3 % so, 99.9 % with the mean). Before the
    first stamp the first value holds, after the last the last.

    Parameters
    ----------
    time : FloatArray
        Stamps [s], increasing, shape (K,).
    values : FloatArray
        Value held from each stamp to the next, shape (K,).
    grid : FloatArray
        Start of each grid period [s], shape (J,).
    period : float
        Grid period [s].

    Returns
    -------
    FloatArray
        Mean of the held signal over each grid period, shape (J,).

    """
    # Integral of the held signal from time[0] to each stamp, then to any instant.
    at_stamps = np.concatenate(([0.0], np.cumsum(values[:-1] * np.diff(time))))

    def integral(instants: FloatArray) -> FloatArray:
        index = np.clip(np.searchsorted(time, instants, side='right') - 1, 0, len(time) - 1)
        return np.asarray(at_stamps[index] + values[index] * (instants - time[index]),
                          dtype=float)

    return np.asarray(np.diff(integral(np.append(grid, grid[-1] + period))) / period,
                      dtype=float)


def read_csv(path: str | Path, plant: str = 'has', limits: Limits = Limits()) -> Measurement:
    """Read a CSV log (header row, one row per sample, SI units) and check it.

    Raises
    ------
    MeasurementError
        For an unreadable file, a value that is not a number (naming row and column), and
        everything :func:`check_columns` refuses.

    """
    source = str(path)
    try:
        with Path(path).open(newline='', encoding='utf-8') as handle:
            reader = csv.reader(handle)
            header = next(reader, None)
            if header is None:
                msg = f'{source}: empty file (a header row is expected)'
                raise MeasurementError(msg)
            names = [name.strip() for name in header]
            rows = list(reader)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        msg = f'cannot read {source}: {exc}'
        raise MeasurementError(msg) from exc
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        msg = f'{source}: column {", ".join(duplicates)} appears twice in the header'
        raise MeasurementError(msg)
    table = np.empty((len(rows), len(names)))
    for i, row in enumerate(rows):
        if len(row) != len(names):
            msg = f'{source}: row {i + 2} has {len(row)} fields, the header {len(names)}'
            raise MeasurementError(msg)
        for j, text in enumerate(row):
            value = text.strip()
            try:
                table[i, j] = float(value) if value else math.nan
            except ValueError:
                msg = f'{source}: row {i + 2}, column {names[j]}: {text!r} is not a number'
                raise MeasurementError(msg) from None
    return check_columns({name: table[:, j] for j, name in enumerate(names)}, plant, source,
                         limits)


def write_csv(measurement: Measurement, path: str | Path) -> None:
    """Write a measurement in the CSV layout :func:`read_csv` reads."""
    names = ['time', measurement.input_name, 'position', *measurement.optional]
    columns = [measurement.time, measurement.input, measurement.position,
               *measurement.optional.values()]
    table = np.column_stack(columns)
    with Path(path).open('w', newline='', encoding='utf-8') as handle:
        writer = csv.writer(handle)
        writer.writerow(names)
        writer.writerows([[f'{v:.9g}' for v in row] for row in table])


def read_bag(path: str | Path, joint: str, limits: Limits = Limits()) -> Measurement:
    """Read one joint's HAS state and command topics from a rosbag2 bag, and check them.

    :func:`bag_columns`, then :func:`check_columns`.

    Raises
    ------
    MeasurementError
        For an unknown joint, a bag without the joint's states, and what
        :func:`check_columns` refuses.
    exo_has_common.errors.BagError
        For a missing, unfinished or corrupt bag (naming the command that recovers it).

    """
    columns, source = bag_columns(path, joint)
    return check_columns(columns, 'has', source, limits)


def bag_columns(path: str | Path, joint: str) -> tuple[dict[str, FloatArray], str]:
    """Read one joint's HAS state and command topics from a rosbag2 bag, as columns.

    The time base is the states' header stamps; the command of a sample is the last
    HasCommand stamped before the middle of the interval that starts at the sample (the
    controller answers each state within a period; a longer latency appears as transport
    delay, which it physically is). A disabled command counts as motor speed 0. Before the
    first command recorded, and without any, the states' ``motor_speed_command`` (the command
    in force at the source) is used: a plant node holds its initial motor speed until its first
    command, and a recorder may subscribe to the commands after the states (taken as 0, they
    stopped the model's motor where the plant's turned at 7.3 rad/s). The cylinder reference
    comes from ``joint_reference`` through the joint's linkage when the bag holds it.

    Returns
    -------
    tuple
        The columns by CSV name (unchecked, the stamps as they are) and the data's origin.

    Raises
    ------
    MeasurementError
        For an unknown joint or a bag without the joint's states.
    exo_has_common.errors.BagError
        For a missing, unfinished or corrupt bag (naming the command that recovers it).

    """
    from exo_has_common.bag import bag_typestore, read_messages
    from exo_has_common.topics import JOINT_REFERENCE_TOPIC, has_command_topic, has_state_topic

    try:
        state_topic = '/' + has_state_topic(joint)
        command_topic = '/' + has_command_topic(joint)
    except ValueError as exc:
        raise MeasurementError(str(exc)) from None
    reference_topic = '/' + JOINT_REFERENCE_TOPIC
    typestore = bag_typestore(path)
    fields = ('position', 'pressure_a', 'pressure_b', 'motor_speed', 'load_force',
              'motor_speed_command')
    states: dict[str, list[float]] = {name: [] for name in fields}
    stamps: list[int] = []
    commands: list[tuple[int, float]] = []
    references: list[tuple[int, float]] = []
    with read_messages(path) as messages:
        for topic, msgtype, _t_ns, data in messages:
            if topic not in (state_topic, command_topic, reference_topic):
                continue
            msg: Any = typestore.deserialize_cdr(data, msgtype)
            stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
            if topic == state_topic:
                stamps.append(stamp)
                for name in fields:
                    states[name].append(float(getattr(msg, name)))
            elif topic == command_topic:
                commands.append((stamp, float(msg.motor_speed) if msg.enable else 0.0))
            elif joint in list(msg.name):
                references.append((stamp, float(msg.position[list(msg.name).index(joint)])))
    source = f'{path} ({joint})'
    if not stamps:
        msg = f'{source}: no messages on {state_topic}'
        raise MeasurementError(msg)
    # Times from the first state's stamp (absolute stamps in float seconds would keep only
    # 0.2 us of resolution).
    origin = min(stamps)
    order = np.argsort(stamps, kind='stable')
    columns = {name: np.asarray(values)[order] for name, values in states.items()}
    columns['time'] = (np.asarray(stamps, dtype=np.int64)[order] - origin) * 1e-9
    command_in_state = columns.pop('motor_speed_command')
    time = columns['time']
    if commands:
        commands.sort()
        sent = (np.array([c[0] for c in commands], dtype=np.int64) - origin) * 1e-9
        values = np.array([c[1] for c in commands])
        half = 0.5 * float(np.median(np.diff(time))) if len(time) > 1 else 0.0
        index = np.searchsorted(sent, time + half, side='left') - 1
        columns['motor_speed_command'] = np.where(index >= 0, values[np.clip(index, 0, None)],
                                                  command_in_state)
    else:
        columns['motor_speed_command'] = command_in_state
    if references:
        from exo_has_common.joints import joint_type_of
        from exo_has_sim.kinematics import Linkage
        from exo_has_sim.parameters import load_parameters

        references.sort()
        linkage = Linkage.from_parameters(load_parameters(joint_type_of(joint)))
        when = (np.array([r[0] for r in references], dtype=np.int64) - origin) * 1e-9
        angle = np.interp(time, when, [r[1] for r in references])
        columns['reference'] = np.asarray(linkage.position(angle), dtype=float)
    return columns, source
