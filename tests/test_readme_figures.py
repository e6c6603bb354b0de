"""The README's figures are its pages' figures: every figure the README quotes beside a link to
a page under docs/ is on that page, and the README stays a first screen (under 150 lines).

The rule, so that a README figure cannot drift from the page it cites:

- The README is cut into blocks outside fenced code: paragraphs, list items, table rows and
  headings. HTML comments, inline code spans (commands and options: `-n 8`, `--tolerance
  1e-3`, `pip install -e .`) and the targets of links are taken out first.
- A block that links pages under docs/ quotes figures. A figure is a date written YYYY-MM-DD,
  or a number that has a decimal point or an exponent (64.3, 1.8e-5), or is followed by a
  unit of measurement: %, dB, x written on the number (11.5x), s, ms, min, h, clips, clips/s,
  runs/s, points. The first number of a range "A-B unit" is a figure with the second. Integers
  without a unit are not figures: sizes (8x3, 4 x 2), counts of things ("12 classes", "2
  cores"), the Python version.
- A block is cut into clauses at semicolons. Each figure must be on one of the pages its
  clause links, or, where its clause links none, on one of the pages its block links.
  Numbers compare as written up to formatting: 20,000 and 20000, 1e-4 and 0.0001, 1.8e-5 and
  1.8e-05, with or without a sign, are the same figure; 5.0 and 5 are not (the digits shown
  must match). Dates compare as text. The check catches a figure that changed on one side; a
  number that the page has elsewhere passes, so it cannot tell a figure quoted for the wrong
  quantity.
- Every link to a page under docs/ resolves: the file exists and an anchor names one of its
  headings.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from decimal import Decimal
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
MAX_LINES = 150

DATE = re.compile(r"\b\d{4}-\d{2}-\d{2}\b")
NUMBER = re.compile(r"(?<![\w.])(?:\d{1,3}(?:,\d{3})+|\d+)(?:\.\d+)?(?:[eE][-+]?\d+)?")
PAGE_NUMBER = re.compile(r"(?<![\d.])(?:\d{1,3}(?:,\d{3})+|\d+)(?:\.\d+)?(?:[eE][-+]?\d+)?")
UNIT = re.compile(r"(?:x(?!\w)|\s?(?:%|dB\b|clips/s|runs/s|clips\b|points\b|min\b|ms\b|s\b|h\b))")
RANGE = re.compile(r"\s?(?:-|–|to)\s?")
LINK = re.compile(r"\[([^\]]*)\]\(([^)\s]+)\)")
COMMENT = re.compile(r"<!--.*?-->", re.S)
CODE_SPAN = re.compile(r"`[^`\n]*`")


def blocks(text: str) -> list[str]:
    """Paragraphs, list items, table rows and headings outside fenced code, comments out."""
    out: list[list[str]] = []
    fenced = False
    for line in COMMENT.sub("", text).splitlines():
        if line.startswith("```"):
            fenced = not fenced
            out.append([])
            continue
        if fenced or not line.strip():
            out.append([])
            continue
        starts = line.startswith(("- ", "* ", "|", "#")) or not out or not out[-1]
        if starts or out[-1][0].startswith(("|", "#")):
            out.append([line])
        else:
            out[-1].append(line.strip())
    return [" ".join(b) for b in out if b]


def docs_links(text: str) -> list[str]:
    """The docs/ pages a piece of README text links (targets as written, anchors kept)."""
    return [target for _, target in LINK.findall(text) if target.startswith("docs/")]


def figures(text: str) -> list[str]:
    """The figures of a piece of README text by the module docstring's rule."""
    text = LINK.sub(lambda m: m.group(1), CODE_SPAN.sub(" ", text))
    found = DATE.findall(text)
    text = DATE.sub(" ", text)
    numbers = list(NUMBER.finditer(text))
    marked = [bool(re.search(r"[.eE]", m.group()) or UNIT.match(text, m.end()))
              for m in numbers]
    for k in range(len(numbers) - 2, -1, -1):  # "60-90 dB": 60 is a figure with 90
        gap = text[numbers[k].end():numbers[k + 1].start()]
        if marked[k + 1] and RANGE.fullmatch(gap):
            marked[k] = True
    return found + [m.group() for m, mark in zip(numbers, marked) if mark]


def key(number: str) -> tuple:
    """A number as written, without its formatting: digits shown and the exponent."""
    digits = Decimal(number.replace(",", "")).as_tuple()
    return digits.digits, digits.exponent


def on_page(figure: str, page: str) -> bool:
    if DATE.fullmatch(figure):
        return figure in page
    return key(figure) in {key(m.group()) for m in PAGE_NUMBER.finditer(page)}


def missing(readme: str, read_page: Callable[[str], str]) -> list[str]:
    """'figure (pages)' for every README figure that none of its pages has."""
    out = []
    for block in blocks(readme):
        links = docs_links(block)
        if not links:
            continue
        for clause in block.split(";"):
            pages = sorted({t.split("#")[0] for t in (docs_links(clause) or links)})
            texts = [read_page(p) for p in pages]
            out += [f"{fig} ({', '.join(pages)}): {clause.strip()[:80]}"
                    for fig in figures(clause) if not any(on_page(fig, t) for t in texts)]
    return out


def slug(heading: str) -> str:
    """GitHub's anchor for a heading."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors(page: str) -> set[str]:
    out, seen = set(), {}
    fenced = False
    for line in page.splitlines():
        if line.startswith("```"):
            fenced = not fenced
        if fenced or not re.match(r"#{1,6} ", line):
            continue
        base = slug(line.lstrip("#"))
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


def read_doc(page: str) -> str:
    return (ROOT / page).read_text(encoding="utf-8")


def test_readme_is_a_first_screen() -> None:
    lines = README.read_text(encoding="utf-8").count("\n")
    assert lines < MAX_LINES, f"README.md has {lines} lines; keep it under {MAX_LINES}"


def test_every_readme_figure_is_on_the_page_it_links() -> None:
    readme = README.read_text(encoding="utf-8")
    checked = sum(len(figures(b)) for b in blocks(readme) if docs_links(b))
    assert checked >= 40, f"only {checked} figures found beside links: is the rule still right?"
    assert missing(readme, read_doc) == []


def test_every_docs_link_of_the_readme_resolves() -> None:
    readme = COMMENT.sub("", README.read_text(encoding="utf-8"))
    bad = []
    for target in sorted(set(docs_links(readme))):
        page, _, anchor = target.partition("#")
        if not (ROOT / page).is_file():
            bad.append(f"{target}: no such file")
        elif anchor and anchor not in anchors(read_doc(page)):
            bad.append(f"{target}: no heading with this anchor")
    assert bad == []


# The rule itself, on a small README and page of its own.
PAGE = """# Results
Measured 2026-11-26 on a 2-core machine: 64.3 +- 3.5%, at eps 0.0001, 20000 clips,
1.8e-05 off, 12,639 runs/s, 60-90 dB.
"""
GOOD = ("On 2026-11-26 ([results](docs/r.md#results)): 64.3 +- 3.5% at eps 1e-4 on 20,000 "
        "clips, Phi within 1.8e-5, 12,639 runs/s, 60-90 dB; the `-n 8 --tolerance 1e-3` "
        "options and 12 classes at 8x3 are not figures.")


@pytest.mark.parametrize("wrong, changed, figure", [
    ("3.5%", "3.6%", "3.6"),                       # a figure changed
    ("2026-11-26 (", "2026-11-27 (", "2026-11-27"),  # another date
    ("1.8e-5", "1.80e-5", "1.80e-5"),              # more digits than the page shows
    ("60-90 dB", "50-90 dB", "50"),                # the start of a range
    ("20,000 ", "21,000 ", "21,000"),
])
def test_a_figure_not_on_its_page_is_found(wrong: str, changed: str, figure: str) -> None:
    pages = {"docs/r.md": PAGE}
    assert missing(GOOD, pages.__getitem__) == []
    bad = missing(GOOD.replace(wrong, changed), pages.__getitem__)
    assert [b.split()[0] for b in bad] == [figure], bad


def test_each_clause_answers_to_its_own_link() -> None:
    pages = {"docs/a.md": "1.5 dB", "docs/b.md": "2.5 dB"}
    text = "One is 1.5 dB ([a](docs/a.md)); the other 2.5 dB ([b](docs/b.md))."
    assert missing(text, pages.__getitem__) == []
    swapped = "One is 2.5 dB ([a](docs/a.md)); the other 1.5 dB ([b](docs/b.md))."
    assert len(missing(swapped, pages.__getitem__)) == 2
