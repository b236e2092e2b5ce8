"""The documentation cannot rot silently: its commands run as written, its links lead somewhere.

Read are README.md, docs/*.md and bench/README.md. In their shell code blocks every command is
parsed by the parser of what it names, as a shell would hand it the words:

- ``exo-has SUBCOMMAND ARGS``: the subcommand must be registered in an ``exo_has.commands``
  entry point of a package's setup.py, and its arguments must parse with that command's own
  argparse parser (its module's ``build_parser()``, or ``_parser()``), up to ``--ros-args``;
  ``exo-has-diagnose ARGS`` (the command of a pip install without ROS) is ``exo-has diagnose``;
- ``ros2 run PACKAGE EXECUTABLE ARGS``: the executable must be a ``console_scripts`` entry of
  that package's setup.py; the arguments before ``--ros-args`` must parse with its parser, or
  be none for a node without one (the container's ``--node`` lists are split by its own code
  and each node class imported);
- ``./run demo ARGS`` is ``exo-has demo ARGS``; ``./run test -m EXPR`` names declared markers;
- ``python bench/SCRIPT.py ARGS``: the script exists and each option is one its parser (or a
  bench module it imports) adds.

In the prose, an inline code span that starts with ``exo-has``, ``ros2 run``, ``./run`` or a
bench script must name what exists and only options it takes (placeholders such as ``BAG`` and
``[...]`` are allowed there). Every relative link and image must lead to a file or folder of the
repository, and a ``#anchor`` to a heading of the page it points at. README.md and docs/ speak
of features, never of issue numbers, and the README stays a page a newcomer reads (250 lines).
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import importlib
import io
import itertools
import re
import shlex
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / 'README.md'
DOCUMENTS = (README, *sorted((ROOT / 'docs').glob('*.md')), ROOT / 'bench' / 'README.md')
#: Pages that speak of features, not of issue numbers.
USER_PAGES = (README, *sorted((ROOT / 'docs').glob('*.md')))
README_MOST_LINES = 250
#: Code blocks read as shell commands, by their info string.
SHELL_BLOCKS = {'', 'bash', 'sh', 'shell', 'console'}
#: Where ROS's own arguments start: what follows is rcl's, not the executable's.
ROS_ARGS = '--ros-args'
#: Words that end one command and start another on a shell line.
SEPARATORS = {'&&', '||', ';', '|', '&', '(', ')'}


@dataclass(frozen=True)
class Entry:
    """An executable or subcommand of a package's setup.py: ``module:function``."""

    package: str
    module: str
    function: str


def _entry_points(setup: Path) -> dict[str, list[str]]:
    """Read the ``entry_points`` dict of a setup.py without running it."""
    for node in ast.walk(ast.parse(setup.read_text())):
        if isinstance(node, ast.Call) and getattr(node.func, 'id', '') == 'setup':
            for keyword in node.keywords:
                if keyword.arg == 'entry_points':
                    value = ast.literal_eval(keyword.value)
                    assert isinstance(value, dict)
                    return value
    return {}


@cache
def entries() -> dict[str, dict[str, Entry]]:
    """Return, by group (``console_scripts``, ``exo_has.commands``), every entry by name.

    Console scripts are keyed ``package/executable``, as ``ros2 run`` finds them.
    """
    found: dict[str, dict[str, Entry]] = {'console_scripts': {}, 'exo_has.commands': {}}
    for setup in sorted(ROOT.glob('exo_has_*/setup.py')):
        package = setup.parent.name
        for group, lines in _entry_points(setup).items():
            for line in lines:
                name, _, target = (part.strip() for part in line.partition('='))
                module, _, function = target.partition(':')
                key = f'{package}/{name}' if group == 'console_scripts' else name
                found.setdefault(group, {})[key] = Entry(package, module, function)
    return found


@cache
def parser_of(module_name: str) -> argparse.ArgumentParser | None:
    """Return the argparse parser a command's module builds, or None for one without."""
    module = importlib.import_module(module_name)
    build = getattr(module, 'build_parser', None) or getattr(module, '_parser', None)
    if build is None:
        return None
    parser = build()
    _spelled_out(parser)
    return parser


def _spelled_out(parser: argparse.ArgumentParser) -> None:
    """Refuse abbreviated options (``--rat`` for ``--rate``): the pages spell them out."""
    parser.allow_abbrev = False
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                _spelled_out(sub)


def options_of(parser: argparse.ArgumentParser) -> set[str]:
    """Return every option string of a parser and of its subcommands' parsers."""
    options = set(parser._option_string_actions)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                options |= options_of(sub)
    return options


def parse_error(parser: argparse.ArgumentParser, args: list[str]) -> str | None:
    """Parse ``args`` as the command would; return argparse's complaint, or None."""
    stderr = io.StringIO()
    try:
        with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
            parser.parse_args(args)
    except SystemExit as exit_:
        if exit_.code not in (0, None):  # --help exits with 0
            return stderr.getvalue().strip().splitlines()[-1]
    return None


@cache
def bench_options(script: Path) -> set[str]:
    """Return every option a bench script's parser adds, its imported bench modules' too."""
    options: set[str] = set()
    tree = ast.parse(script.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, 'attr', '') == 'add_argument':
            options |= {arg.value for arg in node.args
                        if isinstance(arg, ast.Constant) and isinstance(arg.value, str)
                        and arg.value.startswith('-')}
        elif isinstance(node, ast.ImportFrom | ast.Import):
            names = [node.module] if isinstance(node, ast.ImportFrom) else \
                [alias.name for alias in node.names]
            for name in names:
                imported = script.parent / f'{name}.py'
                if name and imported.is_file() and imported != script:
                    options |= bench_options(imported)
    return options | {'-h', '--help'}


def declared_markers() -> set[str]:
    """Return the pytest markers pyproject.toml declares (``--strict-markers`` refuses others)."""
    text = (ROOT / 'pyproject.toml').read_text()
    return set(re.findall(r"^\s*'(\w+):", text, re.MULTILINE))


# --- reading the pages ------------------------------------------------------------------------

FENCE = re.compile(r'^```[ \t]*([\w+-]*)[^\n]*\n(.*?)^```[ \t]*$', re.MULTILINE | re.DOTALL)
INLINE = re.compile(r'(?<!`)`([^`]+)`(?!`)')
LINK = re.compile(r'!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+"[^"]*")?\s*\)')


def shell_blocks(text: str) -> Iterator[str]:
    """Yield the shell code blocks of a Markdown text."""
    for match in FENCE.finditer(text):
        if match.group(1).lower() in SHELL_BLOCKS:
            yield match.group(2)


def prose(text: str) -> str:
    """Return a Markdown text without its code blocks."""
    return FENCE.sub('', text)


def inline_spans(text: str) -> Iterator[str]:
    """Yield the inline code spans of a Markdown text's prose, one broken over lines joined."""
    for match in INLINE.finditer(prose(text)):
        yield ' '.join(match.group(1).split())


def commands_of_block(block: str) -> Iterator[list[str]]:
    """Yield the words of each command of a shell block (continuations joined, no comments)."""
    for line in block.replace('\\\n', ' ').splitlines():
        line = line.strip().removeprefix('$ ')
        lexer = shlex.shlex(line, posix=True, punctuation_chars=True)
        lexer.whitespace_split = True
        try:
            words = list(lexer)
        except ValueError as exc:  # an unbalanced quote: a command no shell would run
            yield ['<unreadable>', f'{line!r}: {exc}']
            continue
        command: list[str] = []
        for word in [*words, ';']:
            if word in SEPARATORS:
                if command:
                    yield command
                command = []
            else:
                command.append(word)


def heading_anchors(text: str) -> set[str]:
    """Return the anchors GitHub gives a page's headings (duplicates numbered)."""
    anchors: set[str] = set()
    for heading in re.findall(r'^#{1,6}[ \t]+(.+?)[ \t#]*$', prose(text), re.MULTILINE):
        slug = re.sub(r'[^\w\- ]', '', heading.replace('`', '').strip().lower()).replace(' ', '-')
        candidate, number = slug, 0
        while candidate in anchors:
            number += 1
            candidate = f'{slug}-{number}'
        anchors.add(candidate)
    return anchors


# --- checking ---------------------------------------------------------------------------------

def check_command(words: list[str], whole: bool = True) -> list[str]:
    """Check one command's words; return what is wrong (nothing for a command not ours).

    ``whole``: the words are a command as run (a code block), parsed in full; otherwise a
    mention in the prose, whose placeholders are let be and whose options alone are checked.
    """
    if words[0] == '<unreadable>':
        return [words[1]]
    for index, word in enumerate(words):
        rest = words[index + 1:]
        if word == 'exo-has' or word.endswith('/exo-has'):
            return _check_exo_has(rest, whole)
        if word == 'exo-has-diagnose':  # the console script of a pip install without ROS
            return _check_exo_has(['diagnose', *rest], whole)
        if word == 'ros2' and rest[:1] == ['run']:
            return _check_ros2_run(rest[1:], whole)
        if word == './run':
            return _check_run(rest, whole)
        if word.startswith('bench/') and word.endswith('.py'):
            return _check_bench(word, rest)
    return []


def _options_in(words: list[str]) -> list[str]:
    """Return the option words of a mention, brackets and trailing punctuation stripped."""
    options = []
    for word in words:
        word = word.strip('[](){},.;|')
        if word == ROS_ARGS:
            break
        if re.fullmatch(r'--?[A-Za-z][\w-]*', word):
            options.append(word)
    return options


def _parse(parser: argparse.ArgumentParser, words: list[str], whole: bool, name: str) -> list[str]:
    args = words[:words.index(ROS_ARGS)] if ROS_ARGS in words else words
    if whole:
        error = parse_error(parser, args)
        return [f'{name} {" ".join(args)}: {error}'] if error else []
    known = options_of(parser)
    return [f'{name}: unknown option {option}' for option in _options_in(args)
            if option not in known]


def _check_exo_has(words: list[str], whole: bool) -> list[str]:
    commands = entries()['exo_has.commands']
    if not words or words[0] in ('-h', '--help'):
        return []
    if words[0] not in commands:
        return [f'exo-has {words[0]}: no such subcommand (known: {", ".join(sorted(commands))})']
    parser = parser_of(commands[words[0]].module)
    assert parser is not None, f'exo-has {words[0]} has no argparse parser to check against'
    return _parse(parser, words[1:], whole, f'exo-has {words[0]}')


def _check_ros2_run(words: list[str], whole: bool) -> list[str]:
    if not whole and (len(words) < 2 or '*' in words[0]):
        return []  # a mention of ros2 run itself, or of a kind of executable
    if len(words) < 2:
        return [f'ros2 run {" ".join(words)}: names no package and executable']
    package, executable, args = words[0], words[1], words[2:]
    if not package.startswith('exo_has_'):
        return []  # another project's executable, or a placeholder (PKG, ...)
    entry = entries()['console_scripts'].get(f'{package}/{executable}')
    if entry is None:
        scripts = sorted(key.split('/')[1] for key in entries()['console_scripts']
                         if key.startswith(f'{package}/'))
        return [f'ros2 run {package} {executable}: no such executable '
                f'(console_scripts of {package}: {", ".join(scripts) or "none, or no package"})']
    name = f'ros2 run {package} {executable}'
    if entry.module == 'exo_has_runtime.container':
        return _check_container(args, whole, name)
    parser = parser_of(entry.module)
    if parser is not None:
        return _parse(parser, args, whole, name)
    own = args[:args.index(ROS_ARGS)] if ROS_ARGS in args else args
    if whole and own:
        return [f'{name}: a node takes its settings after {ROS_ARGS}, got {" ".join(own)}']
    return [f'{name}: unknown option {option}' for option in _options_in(own)]


def _check_container(args: list[str], whole: bool, name: str) -> list[str]:
    from exo_has_runtime import container
    from exo_has_runtime.errors import ContainerArgumentError

    if not whole:
        return [f'{name}: unknown option {option}' for option in _options_in(args)
                if option != container.NODE_FLAG]
    try:
        container.factories(container.split_arguments(args)[1])
    except ContainerArgumentError as exc:
        return [f'{name}: {exc}']
    return []


def _check_run(words: list[str], whole: bool) -> list[str]:
    if not words:
        return []
    action, args = words[0], words[1:]
    if action == 'demo':
        return _check_exo_has(['demo', *args], whole)
    if action == 'test':
        markers = declared_markers()
        return [f'./run test -m {expression}: marker {name} is not declared in pyproject.toml'
                for flag, expression in itertools.pairwise(args) if flag == '-m'
                for name in re.findall(r'\w+', expression)
                if name not in markers | {'not', 'and', 'or'}]
    if action == 'shell':
        return []
    if whole or re.fullmatch(r'[a-z]+', action):
        return [f'./run {action}: no such action (demo, test, shell)']
    return []


def _check_bench(script: str, words: list[str]) -> list[str]:
    path = ROOT / script
    if not path.is_file():
        return [f'{script}: no such script']
    known = bench_options(path)
    return [f'{script}: unknown option {option}' for option in _options_in(words)
            if option not in known]


def check_text(text: str, page: Path) -> list[str]:
    """Check a page's commands, mentions of commands and links; return what is wrong."""
    problems = [problem for block in shell_blocks(text) for words in commands_of_block(block)
                for problem in check_command(words)]
    for span in inline_spans(text):
        words = span.split()
        if words and (words[0] in ('exo-has', 'exo-has-diagnose', './run')
                      or words[:2] == ['ros2', 'run']
                      or re.fullmatch(r'(python )?bench/\w+\.py', ' '.join(words[:2]))
                      or re.fullmatch(r'bench/\w+\.py', words[0])):
            problems += check_command(words, whole=False)
    problems += check_links(text, page)
    return [f'{page.relative_to(ROOT) if page.is_relative_to(ROOT) else page.name}: {problem}'
            for problem in problems]


def check_links(text: str, page: Path) -> list[str]:
    """Check that every relative link and image leads to a file, and an anchor to a heading."""
    problems = []
    for target in LINK.findall(INLINE.sub('', prose(text))):
        if re.match(r'[a-z][a-z0-9+.-]*:', target):  # https:, mailto:
            continue
        path_part, _, anchor = target.partition('#')
        path = (page.parent / path_part).resolve() if path_part else page
        if not path.exists():
            problems.append(f'link {target}: no such file')
        elif anchor and path.suffix == '.md' and anchor not in heading_anchors(path.read_text()):
            problems.append(f'link {target}: no heading #{anchor} in {path.name}')
    return problems


# --- the tests --------------------------------------------------------------------------------

@pytest.mark.parametrize('page', DOCUMENTS, ids=lambda page: str(page.relative_to(ROOT)))
def test_every_command_option_and_link_of_the_page_exists(page: Path) -> None:
    assert page.is_file()
    assert check_text(page.read_text(), page) == []


def test_the_readme_is_short_and_points_at_every_page_of_docs() -> None:
    text = README.read_text()
    assert len(text.splitlines()) <= README_MOST_LINES
    pages = sorted(path.name for path in (ROOT / 'docs').glob('*.md'))
    assert pages, 'docs/ holds the pages by task'
    assert [name for name in pages if f'(docs/{name}' not in text] == []


@pytest.mark.parametrize('page', USER_PAGES, ids=lambda page: str(page.relative_to(ROOT)))
def test_the_user_pages_name_features_not_issue_numbers(page: Path) -> None:
    assert re.findall(r'.{0,30}\bissues? \d+.{0,30}', page.read_text(), re.IGNORECASE) == []


GOOD = """\
```bash
exo-has demo --hardware robot   # a comment --not-an-option
exo-has bag recover bags/x/bag --output bags/y && exo-has diagnose log.csv --joint hip -q
taskset -c 0 ros2 run exo_has_bringup robot_loop --rate 200 \\
    --cpus 1 --realtime-priority 40
ros2 run exo_has_sim plant --ros-args -p joint:=left_hip
ros2 run exo_has_runtime container --node exo_has_sim.plant_node:PlantNode --ros-args -p a:=1
./run test -m 'unit and not slow'
python bench/detection.py --null 40
```

Prose: `exo-has bag recover BAG [--output DIR]`, [a page](../README.md#exo_has), ![x](../bags/).
"""


def test_the_checker_passes_a_page_whose_commands_and_links_exist() -> None:
    assert check_text(GOOD, ROOT / 'docs' / 'page.md') == []


@pytest.mark.parametrize(('snippet', 'wording'), [
    ('```bash\nexo-has demo --no-such-option\n```', 'unrecognized arguments: --no-such-option'),
    ('```bash\nexo-has demo --hardware bus\n```', "invalid choice: 'bus'"),
    ('```bash\nexo-has diagnose --joint hip\n```', 'required: INPUT'),
    ('```bash\nexo-has diagnoze log.csv\n```', 'exo-has diagnoze: no such subcommand'),
    ('```bash\nexo-has-diagnose log.csv --worker 2\n```', 'unrecognized arguments: --worker'),
    ('```bash\nexo-has bag recover b --outptu c\n```', 'unrecognized arguments: --outptu'),
    ('```bash\nros2 run exo_has_sim plnat\n```', 'no such executable'),
    ('```bash\nros2 run exo_has_sim plant -p joint:=left_hip\n```', 'after --ros-args'),
    ('```bash\nros2 run exo_has_bringup robot_loop \\\n  --rat 200\n```', '--rat'),
    ('```bash\nros2 run exo_has_runtime container --node no.such:Node\n```', 'cannot import'),
    ('```bash\n./run tests\n```', 'no such action'),
    ('```bash\n./run test -m quick\n```', 'marker quick'),
    ('```bash\npython bench/detection.py --nul 40\n```', 'unknown option --nul'),
    ('```bash\npython bench/no_such.py\n```', 'no such script'),
    ('Prose: `exo-has replay BAG [--speed F]`.', 'unknown option --speed'),
    ('Prose: `ros2 run exo_has_control pd_control`.', 'no such executable'),
    ('See [the page](docs/no_such_page.md).', 'no such file'),
    ('See ![the plot](docs/images/none.png).', 'no such file'),
    ('See [there](README.md#no-such-heading).', 'no heading #no-such-heading'),
])
def test_the_checker_fails_an_unknown_command_option_or_a_broken_link(snippet, wording) -> None:
    problems = check_text(snippet, ROOT / 'page.md')
    assert len(problems) == 1, problems
    assert wording in problems[0]


def test_the_anchors_are_those_github_gives_headings() -> None:
    text = '# On two machines: a robot\n\n## `exo-has diagnose`, by hand\n\n## Limits\n## Limits\n'
    assert heading_anchors(text) == {'on-two-machines-a-robot', 'exo-has-diagnose-by-hand',
                                     'limits', 'limits-1'}
