"""Finding the commands (and ``bench`` subcommands) of a folder without importing them."""
from __future__ import annotations

import ast
from pathlib import Path


def first_doc_line(path: Path) -> str:
    """First line of a module's docstring, read without importing the module."""
    doc = ast.get_docstring(ast.parse(path.read_text(encoding='utf-8'))) or ''
    return doc.strip().splitlines()[0] if doc.strip() else ''


def discover(folder: Path) -> dict[str, Path]:
    """Command name (``models-info``) -> source file of every module and package in
    ``folder`` (``name.py`` or ``name/__init__.py``; names starting with ``_`` are skipped)."""
    found = {}
    for path in folder.iterdir():
        if path.name.startswith('_'):
            continue
        if path.suffix == '.py':
            found[path.stem] = path
        elif (path / '__init__.py').is_file():
            found[path.name] = path / '__init__.py'
    return {name.replace('_', '-'): found[name] for name in sorted(found)}
