"""``tlessbot <command> ...``: one executable for every tool.

A command is a module ``tlessbot_ros/tools/commands/<command>.py`` (or a package
``commands/<command>/``, as ``bench`` with its subcommands) that defines::

    def add_arguments(parser: argparse.ArgumentParser) -> None: ...
    def run(args: argparse.Namespace) -> int: ...

Its module docstring's first line is the command's help. Only the chosen command's module is
imported, so ``tlessbot --help`` stays fast and one broken tool cannot break the others.
Code the commands share lives in ``tlessbot_ros/tools/support/``; commands never import each
other.
"""
from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.tools.support.discovery import discover, first_doc_line

_COMMANDS_DIR = Path(__file__).resolve().parent / 'commands'
_COMMANDS_PACKAGE = 'tlessbot_ros.tools.commands'


def available_commands() -> dict[str, str]:
    """Command name -> one-line help, read from the module docstrings without importing them."""
    return {name: first_doc_line(path) for name, path in discover(_COMMANDS_DIR).items()}


def _usage(commands: dict[str, str]) -> str:
    width = max((len(c) for c in commands), default=0)
    lines = ['usage: tlessbot <command> [options]', '', 'commands:']
    lines += [f'  {name:<{width}}  {text}' for name, text in commands.items()]
    lines += ['', "Run 'tlessbot <command> --help' for a command's options."]
    return '\n'.join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    commands = available_commands()
    if not argv or argv[0] in ('-h', '--help'):
        print(_usage(commands))
        return 0 if argv else 2
    command = argv[0]
    if command not in commands:
        print(f'tlessbot: unknown command {command!r}\n\n{_usage(commands)}', file=sys.stderr)
        return 2
    module = importlib.import_module(f'{_COMMANDS_PACKAGE}.{command.replace("-", "_")}')
    parser = argparse.ArgumentParser(prog=f'tlessbot {command}', description=module.__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    module.add_arguments(parser)
    args = parser.parse_args(argv[1:])
    try:
        return int(module.run(args) or 0)
    except TlessbotError as error:
        print(f'tlessbot {command}: error: {error}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == '__main__':
    sys.exit(main())
