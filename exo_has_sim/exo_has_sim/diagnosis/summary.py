"""A batch's summary folder: each record's JSON document, summary.md and summary.csv.

``--summary DIR`` holds ``records/<id>.json`` for each record that ended (its diagnosis's
document, or the error that stopped it, each with ``record``: what was diagnosed, how, where and
in how many seconds), written whole or not at all (a temporary file renamed) when the record
ends: a record whose JSON is there is done, and a batch run again skips it. ``summary.md``
and ``summary.csv`` list the batch's records, one :class:`SummaryRow` each: input, joint,
verdict, cause, size, the validated position fits, seconds, and the error of a record that
could not be diagnosed or the reason one was not finished. They are rewritten as each record
ends, and when the batch ends or is interrupted.
"""

from __future__ import annotations

import csv
import io
import json
import os
import tempfile
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from exo_has_sim.diagnosis.records import ERROR, Record

#: The folder of the records' JSON documents, in the summary folder.
RECORDS_FOLDER = 'records'
#: The verdict of a record not finished: its worker died, it failed, or the batch was
#: interrupted first. It has no JSON: the batch run again diagnoses it.
UNFINISHED = 'unfinished'
#: The columns of summary.csv.
COLUMNS = ('input', 'joint', 'verdict', 'cause', 'size', 'unit', 'fit_nominal', 'fit_baseline',
           'fit_extended', 'seconds', 'error', 'json')
#: The verdicts in the order the summary counts them.
VERDICTS = ('effect', 'none', 'structure', ERROR, UNFINISHED)


@dataclass(frozen=True)
class SummaryRow:
    """One record's line of the summary.

    Attributes
    ----------
    record : Record
        The record.
    id : str
        Its id (:func:`~exo_has_sim.diagnosis.records.record_id`).
    verdict : str
        ``'effect'``, ``'none'``, ``'structure'``, :data:`~exo_has_sim.diagnosis.records.ERROR`
        or :data:`UNFINISHED`.
    cause : str
        The first named cause (empty for none).
    size : float or None
        Its size, in ``unit`` (SI).
    unit : str
        The size's unit.
    fits : tuple
        The validated position fit [%] of the nominal, baseline and extended models (None
        where not finite or not made).
    seconds : float or None
        Wall time of the record in its worker [s].
    error : str
        Why the record was not diagnosed (an error) or not finished.
    done_before : bool
        Whether an earlier run had done it (its JSON was there).

    """

    record: Record
    id: str
    verdict: str
    cause: str = ''
    size: float | None = None
    unit: str = ''
    fits: tuple[float | None, float | None, float | None] = (None, None, None)
    seconds: float | None = None
    error: str = ''
    done_before: bool = False

    @classmethod
    def of(cls, record: Record, id: str, doc: dict[str, Any],
           done_before: bool = False) -> SummaryRow:
        """Return the row of a record's JSON document."""
        cause = '' if doc.get('cause', 'none') == 'none' else str(doc['cause'])
        size = doc.get('sizes', {}).get(cause)
        unit = next((row.get('unit', '') for step in doc.get('steps', []) for row in step
                     if row.get('effect') == cause), '')
        nominal = doc.get('fits', {}).get('nominal', {}).get('position')
        return cls(record, id, str(doc.get('verdict', ERROR)), cause,
                   None if size is None else float(size), str(unit),
                   (nominal, doc.get('fit_baseline'), doc.get('fit_extended')),
                   doc.get('record', {}).get('seconds'), str(doc.get('error', '')),
                   done_before)

    @classmethod
    def unfinished(cls, record: Record, id: str, why: str) -> SummaryRow:
        """Return the row of a record not finished, saying why."""
        return cls(record, id, UNFINISHED, error=why)


class SummaryFolder:
    """The folder of ``--summary``: the records' JSON documents and the summary of a batch.

    Parameters
    ----------
    folder : Path
        The folder; made with ``records/`` if need be.

    Raises
    ------
    OSError
        If the folder cannot be made.

    """

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.records = folder / RECORDS_FOLDER
        self.records.mkdir(parents=True, exist_ok=True)

    def json_path(self, id: str) -> Path:
        """Return the path of a record's JSON document."""
        return self.records / f'{id}.json'

    def done(self, id: str) -> dict[str, Any] | None:
        """Return a record's JSON document where an earlier run wrote it, else None."""
        try:
            doc = json.loads(self.json_path(id).read_text(encoding='utf-8'))
        except (OSError, ValueError):
            return None  # not written, or not by this command: the record is done again
        return doc if isinstance(doc, dict) and 'verdict' in doc else None

    def write(self, id: str, doc: dict[str, Any]) -> Path:
        """Write a record's JSON document, whole or not at all; return its path."""
        path = self.json_path(id)
        _write_atomically(path, json.dumps(doc, indent=1) + '\n')
        return path

    def write_summary(self, rows: Sequence[SummaryRow],
                      interrupted: bool = False) -> tuple[Path, Path]:
        """Write summary.md and summary.csv of the rows, each whole; return their paths."""
        table = io.StringIO()
        writer = csv.writer(table, lineterminator='\n')
        writer.writerow(COLUMNS)
        for row in rows:
            writer.writerow([
                row.record.source, row.record.joint or '', row.verdict, row.cause,
                '' if row.size is None else repr(row.size), row.unit,
                *('' if fit is None else f'{fit:.2f}' for fit in row.fits),
                '' if row.seconds is None else f'{row.seconds:.1f}', row.error,
                self._json_name(row)])
        markdown, spreadsheet = self.folder / 'summary.md', self.folder / 'summary.csv'
        _write_atomically(spreadsheet, table.getvalue())
        _write_atomically(markdown, self.markdown(rows, interrupted))
        return markdown, spreadsheet

    def _json_name(self, row: SummaryRow) -> str:
        return '' if row.verdict == UNFINISHED else f'{RECORDS_FOLDER}/{row.id}.json'

    def markdown(self, rows: Sequence[SummaryRow], interrupted: bool = False) -> str:
        """Return summary.md: the counts, a table of the records, the errors in full."""
        lines = ['# Diagnoses', '', counts(rows) + (
            '; the batch was interrupted: the same command diagnoses the records not '
            'finished' if interrupted else '') + '.', '']
        options = {row.record.options for row in rows}
        if len(options) == 1:
            lines += ['Options: ' + ', '.join(f'{key} {value}' for key, value
                                              in options.pop().to_json().items()) + '.', '']
        lines += ['| input | joint | verdict | cause | size | fit nominal / baseline / '
                  'extended [%] | s | JSON |', '|---|---|---|---|---|---|---|---|']
        for row in rows:
            size = '' if row.size is None else f'{row.size:.4g} {row.unit}'.strip()
            fits = ' / '.join('-' if fit is None else f'{fit:.2f}' for fit in row.fits) \
                if row.verdict not in (ERROR, UNFINISHED) else ''
            seconds = '' if row.seconds is None else f'{row.seconds:.1f}'
            name = self._json_name(row)
            cells = [str(row.record.source), row.record.joint or '', row.verdict, row.cause,
                     size, fits, seconds, f'[{row.id}]({name})' if name else '']
            lines.append('| ' + ' | '.join(_cell(cell) for cell in cells) + ' |')
        for verdict, title, note in (
                (ERROR, 'Could not be diagnosed', 'The same data and options give the same '
                 'error: a run again skips them.'),
                (UNFINISHED, 'Not finished', 'A run again diagnoses them.')):
            failed = [row for row in rows if row.verdict == verdict]
            if failed:
                lines += ['', f'## {title}', '', note, '']
                lines += [f'- `{row.record.name}`: {row.error}' for row in failed]
        return '\n'.join(lines) + '\n'


def counts(rows: Sequence[SummaryRow]) -> str:
    """Say how many records there are, and how many of each verdict."""
    by_verdict = Counter(row.verdict for row in rows)
    before = sum(row.done_before for row in rows)
    parts = [f'{by_verdict[verdict]} {verdict}' for verdict in VERDICTS if by_verdict[verdict]]
    return (f'{len(rows)} record{"" if len(rows) == 1 else "s"}: ' + ', '.join(parts or ['none'])
            + (f' ({before} done by an earlier run)' if before else ''))


def _cell(text: str) -> str:
    """Return text fit for a Markdown table's cell."""
    return text.replace('|', '\\|').replace('\n', ' ')


def _write_atomically(path: Path, text: str) -> None:
    """Write a file through a temporary one beside it, renamed over it when complete."""
    handle, temporary = tempfile.mkstemp(prefix=f'.{path.name}.', dir=path.parent)
    try:
        with os.fdopen(handle, 'w', encoding='utf-8') as file:
            file.write(text)
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise

