"""README and the documentation's references (the pages themselves are checked by the strict
MkDocs build of ``make docs``, which CI runs).

- README stays short: at most 200 lines; the rest lives in ``docs/``.
- Every relative link in README points to a file of the repository, and an anchor into a page
  of ``docs/`` to one of its headings.
- Code, configs and pages refer to the documentation by page and section, as
  "docs/design.md, Fragments and keyframes": every such page exists and every section named is a
  heading of it, so renaming a heading without its references fails here.
- No reference to the specification the project was started from ("SPEC §"): the design document
  replaces it.
"""

from __future__ import annotations

import re
import unicodedata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
MAX_README_LINES = 200

#: folders and files whose text may refer to the documentation
SCANNED = ("c3f_slam", "c3f_models", "c3f_demo", "datamodules", "export", "benchmarks", "configs", "docs", "tests",
           "tools", ".ci", "README.md", "Makefile", "pyproject.toml", "mkdocs.yml")
SUFFIXES = {".py", ".md", ".yaml", ".yml", ".toml", ".sh", ""}
#: historical records may quote what they quoted then
SKIPPED = (Path("benchmarks/results/archive"),)

LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
DOC_REF = re.compile(r"docs/([\w-]+\.md)(, )?")
FENCE = re.compile(r"^\s*(```|~~~)")


def slug(heading: str) -> str:
    """The anchor MkDocs gives a heading (Python-Markdown's toc slugify)."""
    text = unicodedata.normalize("NFKD", heading).encode("ascii", "ignore").decode("ascii")
    text = re.sub(r"[^\w\s-]", "", text).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def headings(page: Path) -> list[str]:
    """The headings of a Markdown page (outside fenced code), without the leading #s."""
    found, fenced = [], False
    for line in page.read_text(encoding="utf-8").splitlines():
        if FENCE.match(line):
            fenced = not fenced
        elif not fenced and (m := re.match(r"#{1,6}\s+(.+?)\s*#*\s*$", line)):
            found.append(m.group(1))
    return found


def scanned_files() -> list[Path]:
    files = []
    for name in SCANNED:
        path = ROOT / name
        candidates = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
        for p in candidates:
            rel = p.relative_to(ROOT)
            if p.suffix in SUFFIXES and not any(rel.is_relative_to(s) for s in SKIPPED) \
                    and "__pycache__" not in rel.parts:
                files.append(p)
    return files


def test_readme_is_short():
    lines = README.read_text(encoding="utf-8").count("\n")
    assert lines <= MAX_README_LINES, (
        f"README.md has {lines} lines (at most {MAX_README_LINES}): move details into docs/")


def test_readme_links_resolve():
    text = README.read_text(encoding="utf-8")
    links = [t for t in LINK.findall(text) if not re.match(r"[a-z]+:", t)]
    assert links, "README links to nothing?"
    broken = []
    for target in links:
        path, _, anchor = target.partition("#")
        file = (ROOT / path) if path else README
        if not file.exists():
            broken.append(f"{target}: no such file")
        elif anchor and file.suffix == ".md" and anchor not in {slug(h) for h in headings(file)}:
            broken.append(f"{target}: no heading with anchor #{anchor} in {path or 'README.md'}")
    assert not broken, "README.md:\n" + "\n".join(broken)


def test_doc_references_name_existing_sections():
    pages: dict[str, list[str]] = {}
    broken, seen = [], 0
    for file in scanned_files():
        text = file.read_text(encoding="utf-8", errors="replace")
        for m in DOC_REF.finditer(text):
            page = DOCS / m.group(1)
            where = f"{file.relative_to(ROOT)}:{text.count(chr(10), 0, m.start()) + 1}"
            if not page.exists():
                broken.append(f"{where}: docs/{m.group(1)} does not exist")
                continue
            if not m.group(2):  # the page alone
                continue
            seen += 1
            names = pages.setdefault(m.group(1), headings(page))
            rest = text[m.end():m.end() + 120]
            if not any(rest.startswith(h) for h in names):
                broken.append(f"{where}: docs/{m.group(1)} has no section {rest.splitlines()[0][:60]!r}")
    assert seen > 20, "expected the code to refer to the design document by section"
    assert not broken, "\n".join(broken)


def test_no_references_to_the_old_specification():
    word = re.compile(r"\bSPEC\b")
    hits = [f"{f.relative_to(ROOT)}" for f in scanned_files()
            if f != Path(__file__).resolve() and word.search(f.read_text(encoding="utf-8", errors="replace"))]
    assert not hits, f"'SPEC' in {hits}: refer to docs/design.md (by section) instead"
