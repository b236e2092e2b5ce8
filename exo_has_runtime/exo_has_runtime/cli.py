"""``exo-has``: one command with a subcommand per task, gathered from the installed packages.

Packages register subcommands in the ``exo_has.commands`` entry-point group as
``name = module:function``; the function takes the remaining arguments and returns an exit code.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from importlib.metadata import entry_points

from exo_has_runtime.dds import configure_transport
from exo_has_runtime.errors import DdsConfigurationError

Command = Callable[[Sequence[str]], int]


def subcommands() -> dict[str, Callable[[], Command]]:
    """Return, by name, a loader of each registered subcommand (imported only when run)."""
    return {ep.name: ep.load for ep in entry_points(group='exo_has.commands')}


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``exo-has SUBCOMMAND [ARGS...]``."""
    args = list(sys.argv[1:] if argv is None else argv)
    commands = subcommands()
    if not args or args[0] in ('-h', '--help'):
        names = ', '.join(sorted(commands)) or '(none installed)'
        print(f'usage: exo-has SUBCOMMAND [ARGS...]\nsubcommands: {names}')
        return 0 if args else 2
    name, rest = args[0], args[1:]
    if name not in commands:
        known = ', '.join(sorted(commands))
        print(f'exo-has: unknown subcommand {name!r}; known: {known}', file=sys.stderr)
        return 2
    try:
        # Before any participant of this process or of the nodes it starts (they inherit it).
        warning = configure_transport()
    except DdsConfigurationError as exc:
        print(f'exo-has: {exc}', file=sys.stderr)
        return 2
    if warning:
        print(f'exo-has: warning: {warning}', file=sys.stderr)
    function = commands[name]()
    return int(function(rest) or 0)


if __name__ == '__main__':
    sys.exit(main())
