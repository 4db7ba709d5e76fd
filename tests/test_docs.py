"""The documentation: every relative link resolves, and mkdocs builds it in strict mode.

A link is ``[text](target)`` or ``![alt](target)`` outside code; a relative target must
name an existing file (relative to the page), and a ``#anchor`` must name a heading of
that page, slugged the way mkdocs (Python-Markdown's ``toc``) slugs it.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from markdown.extensions.toc import slugify

ROOT = Path(__file__).resolve().parents[1]

_FENCE = re.compile(r"^```.*?^```", re.M | re.S)
_INLINE_CODE = re.compile(r"`[^`\n]*`")
_LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_HEADING = re.compile(r"^(#{1,6})\s+(.+?)\s*#*\s*$", re.M)
_EXTERNAL = re.compile(r"^[a-z][a-z0-9+.-]*:", re.I)


def doc_pages() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def _prose(text: str) -> str:
    """The text without fenced code blocks and inline code (links there are not links)."""
    return _INLINE_CODE.sub("", _FENCE.sub("", text))


def anchors(page: Path) -> set[str]:
    """The heading ids mkdocs gives ``page`` (duplicates get ``_1``, ``_2``, ...)."""
    seen: set[str] = set()
    for m in _HEADING.finditer(_FENCE.sub("", page.read_text(encoding="utf-8"))):
        title = re.sub(r"`([^`]*)`", r"\1", m.group(2))
        title = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", title)
        slug = slugify(title, "-")
        unique, n = slug, 0
        while unique in seen:
            n += 1
            unique = f"{slug}_{n}"
        seen.add(unique)
    return seen


def _shown(path: Path, base: Path = ROOT) -> str:
    return os.path.relpath(path, base)


def broken_links(page: Path) -> list[str]:
    """Every relative link of ``page`` that does not resolve, with the reason."""
    problems = []
    for m in _LINK.finditer(_prose(page.read_text(encoding="utf-8"))):
        target = m.group(1)
        if _EXTERNAL.match(target):
            continue
        path_part, _, anchor = target.partition("#")
        dest = (page.parent / path_part).resolve() if path_part else page
        where = f"{_shown(page)}: link {target!r}"
        if not dest.is_file():
            problems.append(f"{where}: file {path_part!r} does not exist")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            problems.append(
                f"{where}: no heading with anchor {anchor!r} in {_shown(dest, page.parent)}"
            )
    return problems


def test_there_are_pages_with_links() -> None:
    pages = doc_pages()
    assert (ROOT / "docs" / "index.md") in pages
    n_links = sum(len(_LINK.findall(_prose(p.read_text(encoding="utf-8")))) for p in pages)
    assert n_links >= 20, f"expected the README and docs to link their pages, found {n_links}"


def test_readme_stays_short() -> None:
    n = len((ROOT / "README.md").read_text(encoding="utf-8").splitlines())
    assert n <= 200, f"README.md has {n} lines; the detail belongs in docs/ (at most ~200)"


@pytest.mark.parametrize("page", doc_pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(page: Path) -> None:
    assert broken_links(page) == []


def test_checker_catches_a_broken_link(tmp_path: Path) -> None:
    (tmp_path / "other.md").write_text("# Other page\n", encoding="utf-8")
    bad = tmp_path / "bad.md"
    bad.write_text(
        "# Title\n\n[a](other.md) [b](other.md#other-page) [c](#title) `[d](code.md)`\n"
        "[x](nowhere.md) [y](other.md#nope) ![z](img/missing.png)\n",
        encoding="utf-8",
    )
    assert [p.split(": ", 1)[1] for p in broken_links(bad)] == [
        "link 'nowhere.md': file 'nowhere.md' does not exist",
        "link 'other.md#nope': no heading with anchor 'nope' in other.md",
        "link 'img/missing.png': file 'img/missing.png' does not exist",
    ]


def test_mkdocs_builds_strict(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "index.html").is_file()
    assert (tmp_path / "img" / "dashboard.png").is_file()
    assert (tmp_path / "img" / "centre-dashboard.png").is_file()


_DOC_CITATION = re.compile(r"\bdocs/[\w./-]+\.md\b")


def test_code_cites_existing_doc_pages() -> None:
    """A ``docs/<page>.md`` named in a comment or docstring of our code exists."""
    missing = []
    for layer in ("common", "machine", "estimators", "harness", "server", "tests"):
        for path in sorted((ROOT / layer).rglob("*.py")):
            text = path.read_text(encoding="utf-8")
            for cited in sorted(set(_DOC_CITATION.findall(text))):
                if not (ROOT / cited).is_file():
                    missing.append(f"{path.relative_to(ROOT)} cites {cited}, which does not exist")
    assert missing == []


# ------------------------------------------------------------------ the architecture page
PACKAGES = ("common", "machine", "estimators", "harness", "server")
_MODULE_ROW = re.compile(r"^\|\s*`([\w/]+\.py)`\s*\|", re.M)


def documented_modules(page: Path) -> list[str]:
    """The modules listed (first column of a table row) under the page's "Every module"."""
    text = page.read_text(encoding="utf-8")
    start = text.index("\n## Every module")
    end = text.find("\n## ", start + 1)
    return _MODULE_ROW.findall(text[start : end if end > 0 else len(text)])


def tree_modules(root: Path) -> set[str]:
    """Every module of our packages (``__init__.py`` aside), as a path from ``root``."""
    return {
        p.relative_to(root).as_posix()
        for pkg in PACKAGES
        for p in (root / pkg).rglob("*.py")
        if p.name != "__init__.py"
    }


def module_list_mismatch(page: Path, root: Path) -> list[str]:
    """What is wrong with the page's module list, one line each (empty: it matches)."""
    listed = documented_modules(page)
    tree = tree_modules(root)
    out = [f"{m}: in the tree, not in {page.name}" for m in sorted(tree - set(listed))]
    out += [f"{m}: in {page.name}, not in the tree" for m in sorted(set(listed) - tree)]
    out += [f"{m}: listed twice" for m in sorted({m for m in listed if listed.count(m) > 1})]
    return out


def test_the_architecture_page_lists_every_module() -> None:
    problems = module_list_mismatch(ROOT / "docs" / "architecture.md", ROOT)
    assert problems == [], "docs/architecture.md, section 'Every module':\n" + "\n".join(problems)


def test_the_module_check_names_a_missing_and_an_extra_module(tmp_path: Path) -> None:
    for rel in ("common/a.py", "common/__init__.py", "server/service/b.py", "server/c.py"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("")
    for pkg in PACKAGES:
        (tmp_path / pkg).mkdir(exist_ok=True)
    page = tmp_path / "arch.md"
    page.write_text(
        "# A\n\n## Every module\n\n| module | what |\n|---|---|\n| `common/a.py` | a |\n"
        "| `server/c.py` | c |\n| `server/c.py` | again |\n| `server/gone.py` | gone |\n\n"
        "## Next\n\n| `server/service/b.py` | outside the section |\n"
    )
    assert module_list_mismatch(page, tmp_path) == [
        "server/service/b.py: in the tree, not in arch.md",
        "server/gone.py: in arch.md, not in the tree",
        "server/c.py: listed twice",
    ]
