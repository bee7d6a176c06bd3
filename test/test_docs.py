"""The documentation holds together: links resolve, the README stays short, results.md stays a
table of one-line cells, and the user guide speaks in the present tense (history goes to
docs/bench/)."""
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README_MAX_LINES = 160
RESULTS_CELL_MAX_CHARS = 160
RESULTS_COLUMNS = ('measurement', 'command', 'figure', 'goal', 'report')
LINK = re.compile(r'(?<!!)\[[^\]]*\]\(([^)\s]+)\)')
FENCE = re.compile(r'^```.*?^```', re.MULTILINE | re.DOTALL)
# A docs/ path named in code, tests, scripts or config; a line that names an outside project
# (its own docs/) is skipped.
DOCS_PATH = re.compile(r'(?<![\w/.-])docs/[\w./-]*\w\.md\b')
OUTSIDE_PROJECTS = ('bop_toolkit',)
SHARED_DOCS = REPO.parent / 'shared'   # ../shared/docs: the team's notes, not this repo's
HISTORY = re.compile(r'\bBefore:|\bused to\b|\buntil now\b|\bno longer\b|\bas before\b'
                     r'|\b20\d\d-\d\d-\d\d\b|\b\w+th session\b|\bbranch h[\w-]*', re.IGNORECASE)


def _markdown_files() -> list[Path]:
    return [REPO / 'README.md', *sorted((REPO / 'docs').rglob('*.md'))]


def _guide_pages() -> list[Path]:
    """The user guide: README.md and docs/*.md but the measurement table (dated by design)."""
    return [REPO / 'README.md', *(path for path in sorted((REPO / 'docs').glob('*.md'))
                                  if path.name != 'results.md')]


def _anchors(path: Path) -> set[str]:
    """GitHub's heading anchors of a Markdown file."""
    text = FENCE.sub('', path.read_text(encoding='utf-8'))
    anchors = set()
    for heading in re.findall(r'^#+\s+(.+?)\s*$', text, re.MULTILINE):
        slug = re.sub(r'[^\w\- ]', '', heading.strip().lower()).replace(' ', '-')
        anchors.add(slug)
    return anchors


def _links(path: Path) -> list[str]:
    text = FENCE.sub('', path.read_text(encoding='utf-8'))
    text = re.sub(r'`[^`\n]*`', '', text)
    return LINK.findall(text)


@pytest.mark.parametrize('path', _markdown_files(), ids=lambda p: str(p.relative_to(REPO)))
def test_every_relative_link_resolves(path):
    broken = []
    for target in _links(path):
        if re.match(r'[a-z][a-z0-9+.-]*:', target):      # http:, https:, mailto:
            continue
        file_part, _, anchor = target.partition('#')
        linked = (path.parent / file_part).resolve() if file_part else path
        if not linked.exists():
            broken.append(f'{target}: no such file')
        elif anchor and linked.suffix == '.md' and anchor not in _anchors(linked):
            broken.append(f'{target}: no heading #{anchor} in {linked.name}')
    assert not broken, f'{path.relative_to(REPO)}: ' + '; '.join(broken)


def test_docs_paths_named_in_the_code_exist():
    missing = []
    for folder in ('tlessbot_ros', 'test', 'scripts', 'config', 'launch', 'bags'):
        for path in sorted((REPO / folder).rglob('*')):
            if path.suffix not in ('.py', '.md', '.xml', '.yaml', '.sh') or not path.is_file():
                continue
            for line in path.read_text(encoding='utf-8', errors='replace').splitlines():
                if any(project in line for project in OUTSIDE_PROJECTS):
                    continue
                missing += [f'{path.relative_to(REPO)}: {name}'
                            for name in DOCS_PATH.findall(line)
                            if not (REPO / name).exists() and not (SHARED_DOCS / name).exists()]
    assert not missing, 'docs paths that do not exist: ' + '; '.join(missing)


def test_readme_stays_short():
    lines = (REPO / 'README.md').read_text(encoding='utf-8').count('\n')
    assert lines <= README_MAX_LINES, (
        f'README.md has {lines} lines (at most {README_MAX_LINES}): put the details in a '
        'docs/<topic>.md page and link it')


def _cells(line: str) -> list[str]:
    return [cell.strip() for cell in line.strip().strip('|').split('|')]


def test_results_is_one_line_per_cell():
    lines = (REPO / 'docs' / 'results.md').read_text(encoding='utf-8').splitlines()
    problems, header = [], None
    for number, line in enumerate(lines):
        if not line.startswith('|') or set(line) <= set('|-: '):
            continue
        following = lines[number + 1] if number + 1 < len(lines) else ''
        if following.startswith('|') and set(following) <= set('|-: '):
            header = _cells(line)
            if header[:3] != list(RESULTS_COLUMNS[:3]):
                problems.append(f'a table headed {header}: results.md tables are '
                                f'| {" | ".join(RESULTS_COLUMNS)} |')
            continue
        row = dict(zip(header or (), _cells(line)))
        if not row.get('command') or not row.get('figure'):
            problems.append(f'a row without its command or figure: {line[:80]}')
        problems += [f'a cell of {len(cell)} characters: {cell[:60]}...' for cell in row.values()
                     if len(cell) > RESULTS_CELL_MAX_CHARS]
    assert header, 'docs/results.md has no table'
    assert not problems, ('docs/results.md: one row per measurement, one line per cell (at most '
                          f'{RESULTS_CELL_MAX_CHARS} characters; the story goes to a docs/bench/ '
                          'report): ' + '; '.join(problems))


@pytest.mark.parametrize('path', _guide_pages(), ids=lambda p: str(p.relative_to(REPO)))
def test_the_user_guide_tells_no_history(path):
    text = FENCE.sub('', path.read_text(encoding='utf-8'))
    found = [f'{match.group(0)!r} in "...{text[max(0, match.start() - 40):match.end() + 20]}..."'
             for match in HISTORY.finditer(text)]
    assert not found, (f'{path.relative_to(REPO)} narrates history (move it to a dated report '
                       'in docs/bench/): ' + '; '.join(found))


def _documented_commands() -> dict[tuple[str, ...], dict[str, set[str]]]:
    """(command[, bench name]) -> page -> the --flags the user guide and results.md write
    after it."""
    found: dict[tuple[str, ...], dict[str, set[str]]] = {}
    for path in [*_guide_pages(), REPO / 'docs' / 'results.md']:
        text = path.read_text(encoding='utf-8').replace('\\\n', ' ')
        code = '\n'.join([*FENCE.findall(text), *re.findall(r'`[^`\n]+`', FENCE.sub('', text))])
        for match in re.finditer(r'\btlessbot ([a-z][\w-]*)(?: ([a-z][\w-]*))?[^`\n;|&]*', code):
            command, name = match.group(1), match.group(2)
            key = (command, name) if command == 'bench' and name else (command,)
            flags = set(re.findall(r'(?<![\w-])--[a-z][\w-]*', match.group(0)))
            found.setdefault(key, {}).setdefault(path.name, set()).update(flags)
    return found


@pytest.mark.slow
def test_the_user_guide_uses_only_flags_the_tools_have(capsys):
    from tlessbot_ros.tools import cli
    commands = cli.available_commands()
    unknown = []
    for key, pages in sorted(_documented_commands().items()):
        if key[0] not in commands:
            unknown.append(f'tlessbot {key[0]} (no such command) in {sorted(pages)}')
            continue
        with pytest.raises(SystemExit):
            cli.main([*key, '--help'])
        usage = capsys.readouterr().out
        unknown += [f'{page}: tlessbot {" ".join(key)} {flag}'
                    for page, flags in pages.items() for flag in sorted(flags)
                    if not re.search(rf'(?<![\w-]){re.escape(flag)}(?![\w-])', usage)]
    assert not unknown, 'the docs name options the tools do not have: ' + '; '.join(unknown)
