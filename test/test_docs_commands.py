"""Every `cvj-sim ...` command line and every `make <target>` shown in README.md and docs/*.md
(and every example in a subcommand's ``--help``) agrees with the program: the subcommand exists, its flags exist, a complete command line
parses with the real argparse parser (choices and types included), a scene named on it is a
shipped scene (``cvj-sim scenes``), and the make target is in the Makefile. Nothing is run.

Forms taken from the docs:
* a complete command (code block line or inline code ``cvj-sim run kavz685_lever --duration 2``):
  parsed whole; trailing shell (``# ...``, ``| tail``, ``> f``, ``&&``) is cut first;
* a synopsis (``cvj-sim run SCENE --out DIR [--duration S]``: placeholders in capitals,
  ``[...]``, ``<...>``, ``...`` or ``a|b``): the subcommand and each ``--flag`` must exist;
* a mention (inline ``cvj-sim run`` or ``cvj-sim run --composed``): as a synopsis; an inline
  command may leave out required positionals;
* program output (``cvj-sim run: loop running ...``): skipped.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / 'README.md', *sorted((ROOT / 'docs').glob('*.md'))]

_FENCE = re.compile(r'^\s*```')
_INLINE = re.compile(r'`([^`\n]+)`')
_PLACEHOLDER = re.compile(r'\[|\]|<|>|\.\.\.|\w\|\w')


def _doc_snippets() -> list[tuple[str, str, bool]]:
    """(where, text, inline) for every code-block line (backslash continuations joined)
    and every inline code span of the docs."""
    out: list[tuple[str, str, bool]] = []
    for path in DOCS:
        lines = path.read_text(encoding='utf-8').splitlines()
        in_block = False
        pending = ''
        start = 0
        for no, line in enumerate(lines, 1):
            if _FENCE.match(line):
                in_block = not in_block
                pending = ''
                continue
            where = f'{path.relative_to(ROOT)}:{no}'
            if in_block:
                text = line.strip()
                if text.startswith('$ '):
                    text = text[2:]
                if pending:
                    text = pending + ' ' + text
                else:
                    start = no
                if text.endswith('\\'):
                    pending = text[:-1].strip()
                    continue
                pending = ''
                out.append((f'{path.relative_to(ROOT)}:{start}', text, False))
            else:
                out.extend((where, m.group(1).replace('\\|', '|').strip(), True)
                           for m in _INLINE.finditer(line))   # (\| : a pipe in a table)
    return out


def _help_snippets() -> list[tuple[str, str, bool]]:
    """The example lines of every subcommand's ``--help`` text (its DESCRIPTION), as code."""
    import importlib
    from cvj_ros.commands import COMMANDS as NAMES
    out: list[tuple[str, str, bool]] = []
    for name in NAMES:
        text = getattr(importlib.import_module(f'cvj_ros.commands.{name}'), 'DESCRIPTION', '')
        pending = ''
        for line in text.splitlines():
            line = (pending + ' ' + line.strip()).strip() if pending else line.strip()
            if line.endswith('\\'):
                pending = line[:-1].strip()
                continue
            pending = ''
            out.append((f'cvj-sim {name} --help', line, False))
    return out


def _shell_cut(text: str) -> str:
    """The command without a trailing comment, pipe, redirection or command list."""
    text = re.split(r'\s#', text, maxsplit=1)[0]
    text = re.split(r'\s(?:\|\s|\|$|&&|;|2?>)', text, maxsplit=1)[0]
    return text.strip()


def _cvj_commands() -> list[tuple[str, str, bool]]:
    cmds = []
    for where, text, inline in _doc_snippets() + _help_snippets():
        text = re.sub(r'^(?:[A-Z_][A-Z0-9_]*=\S*\s+)+', '', text)   # ROS_DOMAIN_ID=42 cvj-sim ...
        if not text.startswith('cvj-sim '):
            continue
        words = text.split()
        sub = words[1] if words[1] != '--debug' else (words[2] if len(words) > 2 else '')
        if not re.fullmatch(r'[a-z][a-z_-]*', sub):
            continue   # program output ("cvj-sim run: ...") or "cvj-sim --debug ..."
        cmds.append((where, _shell_cut(text), inline))
    return cmds


def _make_targets() -> list[tuple[str, str]]:
    found = []
    for where, text, _ in _doc_snippets():
        for m in re.finditer(r'(?:^|&&\s*|;\s*)make ([a-zA-Z][\w-]*)', text):
            found.append((where, m.group(1)))
    return found


COMMANDS = _cvj_commands()
MAKE_TARGETS = _make_targets()


@pytest.fixture(scope='module')
def parser() -> argparse.ArgumentParser:
    from cvj_ros.cli import build_parser
    return build_parser()


@pytest.fixture(scope='module')
def subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


@pytest.fixture(scope='module')
def scene_names() -> set[str]:
    from cvj_ros.physics.scene import shipped_scenes
    return set(shipped_scenes())


def _parse(parser: argparse.ArgumentParser,
           argv: list[str]) -> tuple[argparse.Namespace | None, str | None]:
    """(namespace, None) if ``argv`` parses, (None, None) if it asks for --help, else
    (None, argparse's error line)."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            return parser.parse_args(argv), None
        except SystemExit as exc:
            if exc.code not in (0, None):
                return None, err.getvalue().strip().splitlines()[-1]
    return None, None


def test_the_docs_show_commands() -> None:
    """The extraction finds the docs' commands (a broken extractor would pass vacuously)."""
    assert len(COMMANDS) > 100
    assert sum(not inline for _, _, inline in COMMANDS) > 30
    assert len(MAKE_TARGETS) > 20


@pytest.mark.parametrize('where,command,inline', COMMANDS, ids=[c[0] for c in COMMANDS])
def test_doc_command_parses(where: str, command: str, inline: bool,
                            parser: argparse.ArgumentParser,
                            subparsers: dict[str, argparse.ArgumentParser],
                            scene_names: set[str]) -> None:
    from cvj_ros.rosargs import remove_ros_args
    words = remove_ros_args(command.split()[1:])   # ignored by cvj-sim as by rclpy nodes
    if words and words[0] == '--debug':
        words = words[1:]
    sub = words[0]
    assert sub in subparsers, f'{where}: `{command}`: no subcommand {sub!r}'
    options = set(subparsers[sub]._option_string_actions)
    for word in words[1:]:
        flag = word.split('=', 1)[0]
        if flag.startswith('--') and re.fullmatch(r'--[a-z][\w-]*', flag):
            assert flag in options, f'{where}: `{command}`: {sub} has no option {flag}'
    if (_PLACEHOLDER.search(' '.join(words[1:]))
            or any(re.fullmatch(r'[A-Z][A-Z_]*', w) for w in words[1:])):
        return   # a synopsis: subcommand and flags checked
    try:
        argv = remove_ros_args(shlex.split(command)[1:])
    except ValueError as exc:
        pytest.fail(f'{where}: `{command}`: {exc}')
    args, error = _parse(parser, argv)
    missing = re.search(r'the following arguments are required: (.*)', error or '')
    if missing and inline and all(m.startswith('--') for m in missing.group(1).split(', ')):
        # a mention that leaves out a required option (`cvj-sim run SCENE` without --out):
        # give it one, so the scene and the other values are still checked
        for option in missing.group(1).split(', '):
            argv += [option, 'runs/x']
        args, error = _parse(parser, argv)
    if error is not None and inline and ('the following arguments are required' in error
                                         or (words[-1].startswith('--')
                                             and 'expected one argument' in error)):
        return   # a mention of a subcommand or a flag in running text
    assert error is None, f'{where}: `{command}`: {error}'
    method = getattr(args, 'method', None)
    if sub == 'simulate' and method is not None:   # checked after parsing, in the command
        from cvj_ros.physics.scene import OFFLINE_METHODS
        assert method in OFFLINE_METHODS, f'{where}: `{command}`: no method {method!r}'
    scene = getattr(args, 'scene', None)
    if isinstance(scene, str) and '/' not in scene and not scene.endswith(('.yaml', '.yml')):
        assert scene in scene_names, f'{where}: `{command}`: no shipped scene {scene!r}'
    elif isinstance(scene, str) and scene.startswith('config/scenes/'):
        assert (ROOT / scene).is_file(), f'{where}: `{command}`: no file {scene}'


def test_doc_make_targets_exist() -> None:
    makefile = (ROOT / 'Makefile').read_text(encoding='utf-8')
    targets = set(re.findall(r'^([A-Za-z][\w-]*)\s*:(?!=)', makefile, flags=re.M))
    missing = [f'{where}: make {t}' for where, t in MAKE_TARGETS if t not in targets]
    assert not missing, missing
