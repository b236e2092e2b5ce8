"""The numba cache of the compiled model and integrator: stale after an edit of what it inlines."""

import inspect
import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path
from types import ModuleType

import pytest
from numba.core.registry import CPUDispatcher

import exo_has_sim
from exo_has_sim import compiled, control_law, integrator, model, model_jacobian

# Lists the files under a directory, imports the simulator, lists them again, and prints what
# appeared or went, and the source stamp of the closed loop's cache (opened after the listing).
IMPORT_AND_STAMP = """
import json, sys
from pathlib import Path

root = Path(sys.argv[1])
def files():
    return {str(p.relative_to(root)) for p in root.rglob('*') if p.is_file()}

before = files()
import exo_has_sim.plant, exo_has_sim.simulate, exo_has_sim.reference_solution
after = files()
from exo_has_sim import compiled, integrator
assert Path(exo_has_sim.__file__).is_relative_to(root), exo_has_sim.__file__
print(json.dumps({'changed': sorted(before ^ after),
                  'stamp': repr(compiled.source_stamp(integrator.closed_loop))}))
"""


def run_python(code: str, path: Path, *args: str) -> str:
    """Run code in a fresh interpreter importing first from path, with no numba cache dir."""
    env = dict(os.environ, PYTHONPATH=f'{path}{os.pathsep}{os.environ.get("PYTHONPATH", "")}',
               PYTHONDONTWRITEBYTECODE='1')
    env.pop('NUMBA_CACHE_DIR', None)
    result = subprocess.run([sys.executable, '-c', code, *args], env=env, capture_output=True,
                            text=True, timeout=300, check=False)
    assert result.returncode == 0, result.stderr
    return result.stdout.strip().splitlines()[-1]


@pytest.mark.process
def test_importing_writes_no_file_and_an_edit_of_the_model_or_the_law_changes_the_stamp(tmp_path):
    # A copy of the package, whose files may be edited: numba caches in its __pycache__.
    package = tmp_path / 'exo_has_sim'
    shutil.copytree(Path(exo_has_sim.__file__).resolve().parent, package,
                    ignore=shutil.ignore_patterns('__pycache__'))
    stamps = []
    for edited in (None, 'model.py', 'control_law.py', 'gait.py'):
        if edited:
            with (package / edited).open('a') as source:
                source.write('\n# an edit\n')
        report = json.loads(run_python(IMPORT_AND_STAMP, tmp_path, str(tmp_path)))
        assert report['changed'] == [], f'importing wrote or removed files: {report["changed"]}'
        stamps.append(report['stamp'])
    original, model_edited, law_edited, gait_edited = stamps
    assert model_edited != original
    assert law_edited != model_edited
    assert gait_edited == law_edited  # not compiled in


@pytest.mark.process
def test_a_cached_function_is_compiled_again_after_an_edit_of_a_function_it_inlines(tmp_path):
    (tmp_path / 'inner.py').write_text(textwrap.dedent("""
        from numba import njit

        @njit(cache=True)
        def value():
            return 1
    """))
    (tmp_path / 'outer.py').write_text(textwrap.dedent("""
        import inner
        from exo_has_sim.compiled import compiled

        @compiled(inner)
        def outer():
            return inner.value()
    """))
    code = ('import outer; value = outer.outer(); '
            'print(value, sum(outer.outer.stats.cache_hits.values()))')
    assert run_python(code, tmp_path) == '1 0'
    assert run_python(code, tmp_path) == '1 1'  # from the cache
    inner = tmp_path / 'inner.py'
    inner.write_text(inner.read_text().replace('return 1', 'return 2'))
    # numba's own cache would still run the old inner function compiled into outer.
    assert run_python(code, tmp_path) == '2 0'


def called(function: CPUDispatcher) -> set[CPUDispatcher]:
    """Return the compiled functions a compiled function calls, directly or not."""
    found: set[CPUDispatcher] = set()
    pending = [function]
    while pending:
        py_func = pending.pop().py_func
        names = set(py_func.__code__.co_names)
        for name in names:
            value = py_func.__globals__.get(name)
            members = [value] if isinstance(value, CPUDispatcher) else []
            if isinstance(value, ModuleType):
                members = [getattr(value, n) for n in names
                           if isinstance(getattr(value, n, None), CPUDispatcher)]
            for member in members:
                if member not in found:
                    found.add(member)
                    pending.append(member)
    return found


def test_every_compiled_function_declares_the_modules_of_the_compiled_functions_it_calls():
    checked = 0
    for module in (model, model_jacobian, integrator):
        for function in vars(module).values():
            if not isinstance(function, CPUDispatcher):
                continue
            sources = compiled.sources(function)
            for callee in called(function):
                source = Path(inspect.getfile(callee.py_func)).resolve()
                caller, name = function.py_func.__name__, callee.py_func.__name__
                assert source in sources, f'{caller} compiles in {name} of {source.name}'
            checked += 1
    assert checked > 30
    closed_loop = {path.name for path in compiled.sources(integrator.closed_loop)}
    assert {Path(m.__file__).name for m in (model, model_jacobian, control_law)} <= closed_loop
