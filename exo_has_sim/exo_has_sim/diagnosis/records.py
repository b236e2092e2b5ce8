"""The records of a batch: what one is, where the inputs hold them, its id, its diagnosis.

A record is one actuator's data: a CSV log, or one joint of a bag (a rosbag2 directory, or an
``.mcap`` file), with the options it is diagnosed with (:class:`Options`, the command's).
:func:`find_records` finds them in the inputs of ``exo-has diagnose``: files, bags, and folders
searched for both (``--joint all``: every joint a bag records). :func:`record_id` names a record
by its input, its joint and what decides its diagnosis (the content of its files, the options
and the parameters file), so that a batch run again skips the records it has already done and
redoes one whose data or options changed. :func:`diagnosis_of` is one record's diagnosis, the
same for one record on the command line and for each of a batch;
:func:`diagnose_record`, the unit of work that a batch's workers run, returns its JSON
document, or the error that stopped it.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import socket
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from exo_has_common.errors import BagError, ExoHasError
from exo_has_sim.diagnosis.budget import TimeBudget
from exo_has_sim.diagnosis.compare import DEFAULT_HORIZON
from exo_has_sim.diagnosis.diagnose import DEFAULT_BURN_IN, diagnose
from exo_has_sim.diagnosis.loading import load_plant, recorded_joints
from exo_has_sim.diagnosis.report import document
from exo_has_sim.diagnosis.result import Diagnosis
from exo_has_sim.diagnosis.selection import Progress
from exo_has_sim.parameters import CONFIG_DIR

#: ``--joint`` for every joint of a bag.
ALL_JOINTS = 'all'
#: The verdict of a record whose diagnosis stopped at an error of its data or options.
ERROR = 'error'
#: Read in blocks of this many bytes to hash a record's files.
BLOCK = 1 << 20


@dataclass(frozen=True)
class Options:
    """How a record is diagnosed: the options of ``exo-has diagnose`` (its help says each).

    Attributes
    ----------
    plant : str
        ``'has'`` or ``'mass'``.
    load_mass : float or None
        Mass moved by the cylinder [kg].
    params : Path or None
        A parameters file instead of the joint type's.
    horizon : float
        Scored prediction horizon per window [s].
    burn_in : float
        Unscored simulation before each horizon [s].
    constant_load : bool
        The user's word that the load does not vary.
    motor_speed_input : bool
        Drive the pump by the measured motor speed.
    max_causes : int
        Most effects to name.
    time_budget : float or None
        Wall-clock budget of the refining searches [s]; None: no budget.

    """

    plant: str = 'has'
    load_mass: float | None = None
    params: Path | None = None
    horizon: float = DEFAULT_HORIZON
    burn_in: float = DEFAULT_BURN_IN
    constant_load: bool = False
    motor_speed_input: bool = False
    max_causes: int = 2
    time_budget: float | None = None

    def to_json(self) -> dict[str, Any]:
        """Return the options as JSON values (the parameters file as its path)."""
        out = asdict(self)
        out['params'] = None if self.params is None else str(self.params)
        return out


@dataclass(frozen=True)
class Record:
    """One actuator's data to diagnose, and how.

    Attributes
    ----------
    source : Path
        The CSV log or the bag.
    joint : str or None
        The joint read from a bag (None: the only one it records); for a CSV log, a joint
        name or type that picks the parameter set (None: a hip's).
    options : Options
        How it is diagnosed.

    """

    source: Path
    joint: str | None = None
    options: Options = field(default_factory=Options)

    @property
    def name(self) -> str:
        """The record as a reader knows it: the input, and the joint where one is named."""
        return f'{self.source} ({self.joint})' if self.joint else str(self.source)


def is_bag(path: Path) -> bool:
    """Whether a path is a bag: an ``.mcap`` file, or a folder of ``metadata.yaml`` or ``.mcap``.

    A folder with ``.mcap`` files and no ``metadata.yaml`` is a bag its recorder never closed:
    its diagnosis says so, with the command that recovers it.
    """
    if path.suffix == '.mcap':
        return True
    return path.is_dir() and ((path / 'metadata.yaml').is_file() or any(path.glob('*.mcap')))


def find_records(inputs: Sequence[Path], joint: str | None = None,
                 options: Options | None = None,
                 leave_out: Sequence[Path] = ()) -> list[Record]:
    """Return the records the inputs hold, in their order, each once.

    Parameters
    ----------
    inputs : Sequence[Path]
        CSV logs, bags, and folders: a folder that is not a bag is searched, at any depth,
        for ``*.csv`` files and bags (not inside a bag, nor in hidden folders).
    joint : str or None
        ``--joint``: the joint of every bag (:data:`ALL_JOINTS`: each one it records), and for
        the CSV logs the parameter set's joint type (with :data:`ALL_JOINTS`: a hip's).
    options : Options or None
        How every record is diagnosed (default :class:`Options`).
    leave_out : Sequence[Path]
        Folders not searched (the summary's, which holds a ``summary.csv``).

    Notes
    -----
    A path that does not exist, and a bag whose joints cannot be read, are records all the
    same: their diagnosis names the problem, as for one record.

    """
    options = options or Options()
    skipped = {path.resolve() for path in leave_out}
    records: list[Record] = []
    for path in inputs:
        for each in _files(path, skipped) if path.is_dir() and not is_bag(path) else [path]:
            if is_bag(each):
                records += _bag_records(each, joint, options)
            else:
                records.append(Record(each, None if joint == ALL_JOINTS else joint, options))
    return list(dict.fromkeys(records))


def _files(folder: Path, skipped: set[Path]) -> Iterator[Path]:
    """Yield the CSV logs and bags under a folder, sorted, without looking inside a bag."""
    for root, folders, files in os.walk(folder):
        here = Path(root)
        bags = sorted(name for name in folders if is_bag(here / name))
        folders[:] = sorted(name for name in folders if name not in bags
                            and not name.startswith('.')
                            and (here / name).resolve() not in skipped)
        # A folder's .mcap files make it a bag: only CSV logs are left among the files.
        yield from sorted([here / name for name in bags]
                          + [here / name for name in files if name.lower().endswith('.csv')])


def _bag_records(bag: Path, joint: str | None, options: Options) -> list[Record]:
    if joint != ALL_JOINTS:
        return [Record(bag, joint, options)]
    try:
        joints = recorded_joints(bag)
    except BagError:
        joints = []
    # Without a joint, the diagnosis says why (no bag there, never closed, no joint recorded).
    return [Record(bag, name, options) for name in joints] or [Record(bag, None, options)]


def record_id(record: Record, digests: dict[Path, str] | None = None) -> str:
    """Return a record's id: its file name, joint, and a digest of all that decides its diagnosis.

    The digest covers the input's absolute path, the joint, the content of the input's files
    (a bag's every file), the options and the parameters file's content (the joint types'
    files where none is given): the same record with the same data and options keeps its id,
    and a change of any of them gives another. The package's own code is not covered: a
    diagnosis changed by an update of the package is not redone by itself.

    Parameters
    ----------
    record : Record
        The record.
    digests : dict[Path, str] or None
        The digests of the files already hashed, by path, filled as they are hashed (the
        joints of one bag hash it once).

    """
    digests = {} if digests is None else digests

    def digest(path: Path) -> str:
        if path not in digests:
            digests[path] = _content_digest(path)
        return digests[path]

    options = record.options
    params = ([options.params] if options.params is not None
              else sorted(CONFIG_DIR.glob('*.yaml')) if options.plant == 'has' else [])
    h = hashlib.sha256()
    for part in (str(record.source.resolve()), str(record.joint), digest(record.source),
                 repr(sorted(options.to_json().items())),
                 *(digest(Path(path)) for path in params)):
        h.update(part.encode('utf-8') + b'\0')
    stem = re.sub(r'[^A-Za-z0-9_.-]+', '_', record.source.stem)[:60] or 'record'
    joint = f'-{re.sub(r"[^A-Za-z0-9_]+", "_", record.joint)}' if record.joint else ''
    return f'{stem}{joint}-{h.hexdigest()[:16]}'


def _content_digest(path: Path) -> str:
    """Return the SHA-256 of a file, of a folder's files and names, or 'missing'."""
    h = hashlib.sha256()
    if path.is_dir():
        files = sorted(p for p in path.rglob('*') if p.is_file())
    elif path.is_file():
        files = [path]
    else:
        return 'missing'
    for each in files:
        h.update(each.relative_to(path).as_posix().encode('utf-8') + b'\0'
                 if each != path else b'\0')
        try:
            with each.open('rb') as handle:
                while block := handle.read(BLOCK):
                    h.update(block)
        except OSError as exc:
            h.update(f'unreadable: {exc}'.encode())
    return h.hexdigest()


def diagnosis_of(record: Record, progress: Progress | None = None) -> Diagnosis:
    """Read a record, build its plant and diagnose it with its options.

    Raises
    ------
    exo_has_common.errors.ExoHasError, OSError
        For data, a parameters file or options that cannot be used (naming the problem).

    """
    options = record.options
    budget = TimeBudget(math.inf if options.time_budget is None else options.time_budget)
    plant = load_plant(record.source, options.plant, record.joint, options.load_mass,
                       options.params, options.constant_load, options.motor_speed_input)
    return diagnose(plant, options.horizon, options.burn_in, max_causes=options.max_causes,
                    budget=budget, progress=progress)


def diagnose_record(record: Record) -> dict[str, Any]:
    """Diagnose a record: its JSON document (``--json``'s), or its error's, with ``record``.

    The unit of work of a batch's workers. ``record`` says what was diagnosed, how, where
    (``host:pid``) and in how many seconds. Data or options that cannot be used give a
    document whose ``verdict`` is :data:`ERROR` and whose ``error`` names the problem; any
    other exception is a fault of the diagnosis and propagates.
    """
    started = time.perf_counter()
    try:
        doc = document(diagnosis_of(record))
    except (ExoHasError, OSError) as exc:
        doc = {'verdict': ERROR, 'error': str(exc)}
    doc['record'] = {'input': str(record.source), 'joint': record.joint,
                     'options': record.options.to_json(),
                     'worker': f'{socket.gethostname()}:{os.getpid()}',
                     'seconds': round(time.perf_counter() - started, 3)}
    return doc
