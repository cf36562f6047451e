"""Every relative link in README.md and docs/*.md points at a file that exists and, when it has
a `#fragment`, at a heading (GitHub's slug: lower case, punctuation dropped, spaces to '-',
'-1', '-2' ... for repeats) or an explicit `<a id="...">` of that file. A heading renamed
without its links would otherwise send a reader to the top of the page."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / 'README.md', *sorted((ROOT / 'docs').glob('*.md'))]

_LINK = re.compile(r'\]\(([^)\s]+)\)')
_HEADING = re.compile(r'^#{1,6}\s+(.*?)\s*#*\s*$')
_EXPLICIT = re.compile(r'<a\s+(?:id|name)="([^"]+)"')


def github_slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, characters other than word characters,
    '-' and ' ' dropped, each space one '-'."""
    return re.sub(r'[^\w\- ]', '', heading.strip().lower()).replace(' ', '-')


def anchors(path: Path) -> set[str]:
    """The fragments a link into `path` may name (headings outside code blocks, explicit ids)."""
    out: set[str] = set()
    seen: dict[str, int] = {}
    fenced = False
    for line in path.read_text(encoding='utf-8').splitlines():
        if line.lstrip().startswith('```'):
            fenced = not fenced
            continue
        if fenced:
            continue
        out.update(_EXPLICIT.findall(line))
        m = _HEADING.match(line)
        if m:
            slug = github_slug(m.group(1))
            n = seen.get(slug, 0)
            seen[slug] = n + 1
            out.add(slug if n == 0 else f'{slug}-{n}')
    return out


def _links() -> list[tuple[str, Path, str]]:
    found = []
    for path in DOCS:
        for m in _LINK.finditer(path.read_text(encoding='utf-8')):
            target = m.group(1)
            if re.match(r'^[a-z]+:', target):          # http:, https:, mailto:
                continue
            found.append((f'{path.relative_to(ROOT)} -> {target}', path, target))
    return found


def test_github_slug_matches_known_headings() -> None:
    assert github_slug('Python per exchange: profiled and cut') == 'python-per-exchange-profiled-and-cut'
    assert github_slug('Outside nodes: hooking in a vehicle stack') == 'outside-nodes-hooking-in-a-vehicle-stack'
    assert github_slug('Vehicle scenes: differentials, wheels, tyres (`cvj_ros/physics/tree.py`)') \
        == 'vehicle-scenes-differentials-wheels-tyres-cvj_rosphysicstreepy'


def test_the_docs_have_links() -> None:
    assert len(_links()) > 20


@pytest.mark.parametrize(('where', 'path', 'target'), _links(), ids=[w for w, _, _ in _links()])
def test_doc_link_resolves(where: str, path: Path, target: str) -> None:
    file_part, _, fragment = target.partition('#')
    dest = (path.parent / file_part).resolve() if file_part else path
    assert dest.exists(), f'{where}: no file {dest.relative_to(ROOT) if dest.is_relative_to(ROOT) else dest}'
    if fragment and dest.suffix == '.md':
        assert fragment in anchors(dest), f'{where}: no heading or <a id> "{fragment}" in {dest.name}'
