"""
The commands the user docs show, as a user types them, for the tests that run them.

The user docs are README.md and the guide pages its sections moved to (:data:`GUIDE_PAGES`:
install, nodes and launch files, experiments, two computers, tests, messages, change notes),
read as one text in that order.

A command is every line of a fenced ``bash`` (or ``sh``) block, shell line continuations
joined and comments dropped, and every inline code span whose first word is an ``emfc-*``
console script or a ``tools/`` script (the offline-commands table, the prose). Its
normalised form (:func:`normalise`: the words as the shell splits them, joined by single
spaces, quotes removed, ``tools/`` written ``./tools/``) is the key of
``test/readme_commands.yaml``, the registry that names the tests running each command
(``test/test_readme_commands.py`` checks it both ways).
"""

from __future__ import annotations

import os
from pathlib import Path
import re
import shlex
import subprocess
import sys
from typing import List, Optional, Sequence, Tuple

from ros_harness import scaled

REPO = Path(__file__).resolve().parents[1]
README = REPO / 'README.md'
#: The pages whose commands are tests like the README's (README.md first).
GUIDE_PAGES = (README,) + tuple(REPO / 'docs' / f'{name}.md' for name in (
    'install', 'nodes', 'experiments', 'two_computers', 'testing', 'messages', 'changes'))
FENCE = re.compile(r'^\s*(`{3,}|~{3,})\s*([\w+-]*)')
SHELL_BLOCKS = ('bash', 'sh', 'shell', 'console')
#: The console scripts of setup.py (an inline ``emfc-<name>`` is a command if it is one).
SCRIPTS = tuple(sorted(set(re.findall(r"'(emfc-[a-z-]+)': 'emfc_ros",
                                      (REPO / 'setup.py').read_text()))))


def normalise(command: str) -> str:
    """
    The registry key of a command: its shell words joined by single spaces.

    Parameters
    ----------
    command : str
        The command as shown (continuations, comments and quotes allowed).

    Returns
    -------
    str
        Words as the shell splits them (quotes removed, comments dropped), whitespace inside
        a word collapsed, ``tools/`` scripts written ``./tools/...``; empty for a comment line.
    """
    words = shlex.split(command.replace('\\\n', ' '), comments=True)
    words = [' '.join(w.split()) for w in words]
    if words and words[0].startswith('tools/'):
        words[0] = './' + words[0]
    return ' '.join(words)


def fenced_commands(text: str) -> List[Tuple[int, str]]:
    """
    Every command of the fenced shell blocks.

    Parameters
    ----------
    text : str
        Markdown.

    Returns
    -------
    list of (int, str)
        Line number (1-based, of the command's first line) and the normalised command.
    """
    return [(number, normalise(raw)) for number, raw in _raw_fenced(text) if normalise(raw)]


def inline_commands(text: str, scripts: Sequence[str] = SCRIPTS) -> List[Tuple[int, str]]:
    """
    Inline code spans (outside fenced blocks) that are commands.

    Parameters
    ----------
    text : str
        Markdown.
    scripts : sequence of str
        Console script names that make a span a command.

    Returns
    -------
    list of (int, str)
        Line number and normalised command of every span whose first word is one of
        ``scripts`` or a ``tools/*.sh`` script.
    """
    lines, fence = [], None
    for line in text.splitlines():
        match = FENCE.match(line)
        if fence is None and match:
            fence = match.group(1)
            lines.append('')
        elif fence is not None:
            if match and match.group(1).startswith(fence) and not match.group(2):
                fence = None
            lines.append('')
        else:
            lines.append(line)
    prose = '\n'.join(lines)
    out = []
    for match in re.finditer(r'(?<!`)`([^`]+)`(?!`)', prose):
        span = ' '.join(match.group(1).split())
        first = span.split(' ')[0]
        if first in scripts or re.fullmatch(r'(\./)?tools/[\w-]+\.sh', first):
            out.append((prose.count('\n', 0, match.start()) + 1, normalise(span)))
    return out


def user_docs_text() -> str:
    """
    README.md and the guide pages as one Markdown text (:data:`GUIDE_PAGES`, in order).

    Returns
    -------
    str
        The pages joined by blank lines.
    """
    return '\n\n'.join(page.read_text() for page in GUIDE_PAGES)


def readme_commands(text: Optional[str] = None) -> List[Tuple[int, str]]:
    """
    Every command the user docs show, in order, each once.

    Parameters
    ----------
    text : str, optional
        Markdown (README.md and the guide pages, :func:`user_docs_text`, when absent).

    Returns
    -------
    list of (int, str)
        Line number of the first occurrence and normalised command.
    """
    text = user_docs_text() if text is None else text
    seen, out = set(), []
    for number, command in sorted(fenced_commands(text) + inline_commands(text)):
        if command not in seen:
            seen.add(command)
            out.append((number, command))
    return out


def readme_command(prefix: str, *contains: str) -> str:
    """
    The one README command starting with ``prefix`` and containing every ``contains``.

    A command equal to ``prefix`` (and no ``contains``) is that command.

    Parameters
    ----------
    prefix : str
        Start of the normalised command.
    *contains : str
        Text the command must hold too.

    Returns
    -------
    str
        The normalised command (a test runs ``shlex.split`` of it).

    Raises
    ------
    AssertionError
        If none or several commands match (the README changed: update the test).
    """
    commands = [c for _, c in readme_commands()]
    if not contains and prefix in commands:
        return prefix                               # the whole command
    found = [c for c in commands if c.startswith(prefix) and all(p in c for p in contains)]
    assert len(found) == 1, (prefix, contains, found)
    return found[0]


def readme_argv(prefix: str, *contains: str) -> List[str]:
    """
    The README command as the shell passes it to the program (its words).

    Parameters
    ----------
    prefix : str
        Start of the normalised command.
    *contains : str
        Text the command must hold too.

    Returns
    -------
    list of str
        The words, quotes removed, as from the shell.
    """
    text = user_docs_text()
    for _, raw in _raw_fenced(text):
        if normalise(raw) == readme_command(prefix, *contains):
            return shlex.split(raw.replace('\\\n', ' '), comments=True)
    command = readme_command(prefix, *contains)       # an inline span: plain words
    return command.split(' ')


def fenced_argvs(text: str) -> List[List[str]]:
    """
    Every fenced shell command of a Markdown text as the shell passes it (its words).

    Parameters
    ----------
    text : str
        Markdown (a docs page).

    Returns
    -------
    list of list of str
        Per command its words, quotes removed, continuations joined, comments dropped.
    """
    words = [shlex.split(raw.replace('\\\n', ' '), comments=True) for _, raw in _raw_fenced(text)]
    return [w for w in words if w]


def _raw_fenced(text: str) -> List[Tuple[int, str]]:
    """Fenced shell commands as written (continuations kept, lines stripped)."""
    out, fence, shell, pending, start = [], None, False, '', 0
    for number, line in enumerate(text.splitlines(), 1):
        match = FENCE.match(line)
        if fence is None:
            if match:
                fence, shell = match.group(1), match.group(2).lower() in SHELL_BLOCKS
            continue
        if match and match.group(1).startswith(fence) and not match.group(2):
            fence = None
            continue
        if not shell:
            continue
        if not pending:
            start = number
        pending += line.strip() + '\n'
        if line.rstrip().endswith('\\'):
            continue
        out.append((start, pending))
        pending = ''
    return out


def check_tools_venv() -> None:
    """
    Fail unless this test's environment is the tools' venv, installed from these sources.

    ``tools/*.sh`` run ``tools/setup_env.sh`` first; in a current venv that installs nothing
    (it prints nothing and takes well under a second), so a test that runs a ``tools/`` line
    with ``EMFC_VENV`` set to its own environment never reinstalls what it runs in.

    Raises
    ------
    AssertionError
        Saying what is stale (run the suite with ``./tools/test.sh``, which sets it up).
    """
    env = dict(os.environ, EMFC_VENV=sys.prefix)
    check = subprocess.run([str(REPO / 'tools' / 'setup_env.sh'), '--check'],
                           capture_output=True, text=True, timeout=scaled(60), env=env)
    assert check.returncode == 0, (
        f'{sys.prefix} is not the current tools venv ({check.stderr.strip()}): run the suite '
        'with ./tools/test.sh, which sets it up')
