"""The documentation stays readable and its links resolve.

Limits: README.md <= 12,000 characters; no paragraph over 120 words and no sentence over 50 words in README.md,
docs/*.md and the first table of results/README.md (the "did it reproduce?" table), whose cells hold <= 30 words
each; every relative link of every Markdown file in the repository resolves to an existing file or folder.

How text is counted (``prose_paragraphs``, ``sentences``, ``word_count``):

- a *paragraph* is a run of consecutive non-blank lines outside fenced code blocks; headings, table rows and HTML
  comments are not prose and are skipped; each list item ("- ", "* ", "1. ") starts a paragraph of its own;
- a *sentence* ends at ".", "?", "!" or ":" followed by whitespace (so "Fig. 4" or "e.g. x" also end one: the count
  errs towards shorter sentences, never longer ones); a semicolon does not end a sentence;
- a *word* is a whitespace-separated token holding at least one letter or digit ("±", "/", "->" are not words);
  a link counts its text, not its target.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

README_MAX_CHARS = 12_000
PARAGRAPH_MAX_WORDS = 120
SENTENCE_MAX_WORDS = 50
ANSWER_CELL_MAX_WORDS = 30

_FENCE = re.compile(r"^\s*(```|~~~)")
_LIST_ITEM = re.compile(r"^\s*(?:[-*+]|\d+[.)])\s+")
_LINK_TARGET = re.compile(r"\]\([^)]*\)")
_INLINE_LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_REFERENCE_DEFINITION = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+.*)?$")
_INLINE_CODE = re.compile(r"`+[^`]*`+")
_SENTENCE_END = re.compile(r"(?<=[.?!:])\s+")
_SKIPPED_PARTS = {"runs", "node_modules", "shared"}


def word_count(text: str) -> int:
    """Words of a piece of Markdown: tokens with a letter or digit, a link counted by its text only."""
    text = _LINK_TARGET.sub("]", text)
    return sum(1 for token in text.split() if any(ch.isalnum() for ch in token))


def sentences(text: str) -> list[str]:
    """A paragraph's sentences (split after ".", "?", "!" or ":" followed by whitespace)."""
    return [part for part in _SENTENCE_END.split(" ".join(text.split())) if part]


def outside_code(lines: list[str]) -> list[str]:
    """The lines with fenced code blocks replaced by blank lines (line numbers keep their place)."""
    kept, fenced = [], False
    for line in lines:
        if _FENCE.match(line):
            fenced = not fenced
            kept.append("")
        else:
            kept.append("" if fenced else line)
    return kept


def prose_paragraphs(markdown: str) -> list[str]:
    """The prose paragraphs of a Markdown text (see the module docstring)."""
    paragraphs: list[list[str]] = []
    current: list[str] = []
    for line in [*outside_code(markdown.splitlines()), ""]:
        stripped = line.strip()
        not_prose = not stripped or stripped.startswith(("#", "|", "<!--"))
        if not_prose or _LIST_ITEM.match(line):
            if current:
                paragraphs.append(current)
            current = [] if not_prose else [_LIST_ITEM.sub("", stripped)]
        else:
            current.append(stripped)
    return [" ".join(paragraph) for paragraph in paragraphs]


def table_rows(markdown: str, index: int = 0) -> list[list[str]]:
    """The cells of the body rows of the ``index``-th table of a Markdown text (header and divider left out).

    A "|" inside inline code is not a cell border."""
    tables: list[list[str]] = []
    current: list[str] = []
    for line in [*outside_code(markdown.splitlines()), ""]:
        if line.lstrip().startswith("|"):
            current.append(line.strip())
        elif current:
            tables.append(current)
            current = []
    rows = []
    for line in tables[index][2:]:
        masked = _INLINE_CODE.sub(lambda match: match.group(0).replace("|", "\0"), line.replace("\\|", "\0"))
        rows.append([cell.strip().replace("\0", "|") for cell in masked.strip("|").split("|")])
    return rows


def too_long(paragraphs: list[str], max_paragraph: int, max_sentence: int) -> list[str]:
    """One message per paragraph over ``max_paragraph`` words or sentence over ``max_sentence`` words."""
    problems = []
    for paragraph in paragraphs:
        if word_count(paragraph) > max_paragraph:
            problems.append(f"paragraph of {word_count(paragraph)} words: {paragraph[:80]}...")
        for sentence in sentences(paragraph):
            if word_count(sentence) > max_sentence:
                problems.append(f"sentence of {word_count(sentence)} words: {sentence[:80]}...")
    return problems


def relative_links(markdown: str) -> list[str]:
    """The relative link targets of a Markdown text (no URLs, no pure anchors; "#..." stripped), outside code."""
    targets = []
    for line in outside_code(markdown.splitlines()):
        line = _INLINE_CODE.sub("", line)
        found = _INLINE_LINK.findall(line)
        definition = _REFERENCE_DEFINITION.match(line)
        if definition:
            found.append(definition.group(1))
        for target in found:
            if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target) or target.startswith("#"):
                continue  # http:, https:, mailto: ... or an anchor on the same page
            targets.append(target.split("#", 1)[0])
    return targets


def markdown_files() -> list[Path]:
    """Every Markdown file of the repository, outside hidden folders, run outputs and installed packages."""
    files = []
    for path in sorted(ROOT.rglob("*.md")):
        parts = path.relative_to(ROOT).parts[:-1]
        if any(p.startswith(".") or p in _SKIPPED_PARTS or p.endswith(".egg-info") for p in parts):
            continue
        files.append(path)
    return files


def documentation_pages() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


# --- the helpers themselves, on a small synthetic text --------------------------------------------------------

SYNTHETIC = """# A heading that is not prose

First paragraph. It has two sentences: and a colon
that ends a third, across a line break.

```python
x = "code. is. not. prose. " * 500
```

| table | rows |
|---|---|
| are | skipped `a|b` |

- a list item is a paragraph
- so is this one, with [a link](docs/missing.md#anchor) and [a URL](https://example.org/x.md) and [](#top)

[ref]: results/README.md
"""


def test_word_count_counts_words_not_symbols_or_link_targets():
    assert word_count("97.2 ± 2.4 / 96.8 -> done") == 4
    assert word_count("see [the results page](results/README.md#did-it-reproduce)") == 4


def test_paragraphs_skip_code_headings_and_tables_and_split_list_items():
    paragraphs = prose_paragraphs(SYNTHETIC)
    assert paragraphs[0] == "First paragraph. It has two sentences: and a colon that ends a third, across a line break."
    assert paragraphs[1] == "a list item is a paragraph"
    assert paragraphs[2].startswith("so is this one")
    assert len(paragraphs) == 4  # the reference definition is a paragraph too
    assert not any("code." in p or "rows" in p or "heading" in p for p in paragraphs)


def test_sentences_split_after_full_stop_question_exclamation_and_colon():
    assert sentences("One two. Three? Four! Five: six; seven.") == [
        "One two.",
        "Three?",
        "Four!",
        "Five:",
        "six; seven.",
    ]
    assert sentences("version 0.9.2 stays whole") == ["version 0.9.2 stays whole"]


def test_limits_catch_a_long_sentence_and_a_long_paragraph():
    long_sentence = " ".join(["word"] * 51) + "."
    assert too_long([long_sentence], 120, 50) == [f"sentence of 51 words: {long_sentence[:80]}..."]
    long_paragraph = " ".join(["Short sentence here."] * 41)  # 123 words in sentences of 3
    assert len(too_long([long_paragraph], 120, 50)) == 1
    assert too_long(["Fine. Short."], 120, 50) == []


def test_table_rows_and_links_of_the_synthetic_text():
    assert table_rows(SYNTHETIC) == [["are", "skipped `a|b`"]]
    assert relative_links(SYNTHETIC) == ["docs/missing.md", "results/README.md"]


# --- the repository's pages -------------------------------------------------------------------------------------


def test_readme_fits_a_front_page():
    size = len((ROOT / "README.md").read_text())
    assert size <= README_MAX_CHARS, f"README.md has {size} characters (limit {README_MAX_CHARS})"


def test_readme_and_docs_have_short_paragraphs_and_sentences():
    problems = []
    for page in documentation_pages():
        found = too_long(prose_paragraphs(page.read_text()), PARAGRAPH_MAX_WORDS, SENTENCE_MAX_WORDS)
        problems += [f"{page.relative_to(ROOT)}: {problem}" for problem in found]
    assert not problems, "\n".join(problems)


def test_results_page_opens_with_a_short_answer_table():
    rows = table_rows((ROOT / "results" / "README.md").read_text(), 0)
    assert len(rows) >= 12, "the first table has one row per paper item"
    problems = []
    for row in rows:
        for cell in row:
            if word_count(cell) > ANSWER_CELL_MAX_WORDS:
                problems.append(f"cell of {word_count(cell)} words: {cell[:80]}...")
        problems += too_long(row, PARAGRAPH_MAX_WORDS, SENTENCE_MAX_WORDS)
    verdicts = {row[3].strip("*").split()[0].strip(",;:").lower() for row in rows}
    assert verdicts <= {"yes", "partly", "no"}, f"the fourth column holds yes / partly / no, got {verdicts}"
    assert not problems, "\n".join(problems)


def test_every_relative_markdown_link_resolves():
    files = markdown_files()
    assert ROOT / "README.md" in files and any(path.parent == ROOT / "docs" for path in files)
    broken = []
    for path in files:
        for target in relative_links(path.read_text()):
            if target and not (path.parent / target).exists():
                broken.append(f"{path.relative_to(ROOT)}: {target}")
    assert not broken, "links to nothing:\n" + "\n".join(broken)
