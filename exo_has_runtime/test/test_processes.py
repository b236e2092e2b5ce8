"""Tests of exo_has_runtime.processes: modules run as processes for tests."""

from __future__ import annotations

import pytest

from exo_has_runtime.processes import NodeProcess

pytestmark = pytest.mark.process  # every test here starts processes


def test_a_process_started_with_stdin_reads_the_lines_sent_to_it(tmp_path) -> None:
    # json.tool echoes what it reads once its input closes: proof the line got through.
    with NodeProcess('json.tool', log_path=tmp_path / 'echo.log', stdin=True) as process:
        process.send('{"answer": 42}')
        assert process.process.stdin is not None
        process.process.stdin.close()
        assert process.wait() == 0
        assert '"answer": 42' in process.output


def test_sending_without_a_pipe_or_after_the_end_names_the_problem(tmp_path) -> None:
    with NodeProcess('json.tool', log_path=tmp_path / 'none.log') as process:
        with pytest.raises(RuntimeError, match='without a pipe'):
            process.send('{}')
        process.wait()
    with NodeProcess('json.tool', log_path=tmp_path / 'ended.log', stdin=True) as process:
        assert process.process.stdin is not None
        process.process.stdin.close()
        process.wait()
        with pytest.raises(RuntimeError, match='has ended'):
            process.send('{}')


def test_a_temporary_log_is_read_after_the_end_and_removed_with_its_process() -> None:
    import gc

    process = NodeProcess('json.tool', ['--help'])
    assert process.wait() == 0
    process.stop()
    assert 'usage' in process.output
    log = process.log_path
    del process
    gc.collect()
    assert not log.exists()


def test_a_log_the_caller_named_is_kept(tmp_path) -> None:
    with NodeProcess('json.tool', ['--help'], log_path=tmp_path / 'kept.log') as process:
        process.wait()
    del process
    assert (tmp_path / 'kept.log').read_text().startswith('usage')
