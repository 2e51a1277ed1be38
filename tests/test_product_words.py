"""The product speaks of the library, not of how it was built.

README, docs, code, configs, tests, benchmarks, scripts and the Makefile must not use process words (the
patterns below: the word for a working period, issue numbers, a machine on loan, a "turn" as a unit of work;
pytest's ``scope`` value of that first word is an API name and allowed, and the physical turn of a knob is fine).
This file spells the words in pieces, so that it passes its own check and a plain grep of the product.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHECKED = ("README.md", "Makefile", "pyproject.toml", "docs", "dexmots_rl", "configs", "tests", "benchmarks", "scripts")
SKIPPED_DIRS = {".git", ".venv", "__pycache__", ".pytest_cache", "runs", "tables", "build", "dist"}
TEXT_SUFFIXES = {".py", ".md", ".yaml", ".yml", ".toml", ".txt", ".cfg", ".ini", ".json", ".xml", ".sh", ".csv", ""}

SESS, ISS, LNT = "sess" + "ion", "iss" + "ue", "le" + "nt"
PROCESS_WORDS = re.compile(
    rf"\b{SESS}s?\b"
    rf"|\b{ISS}\s*#\s*\d"
    rf"|\b{LNT}\b"
    r"|\b(?:this|that|previous|next|earlier|later|current) turn\b"
    r"|\bturns?\s*#\s*\d",
    re.IGNORECASE,
)
ALLOWED = re.compile(rf"""scope\s*=\s*["']{SESS}["']""")


def product_files():
    for name in CHECKED:
        path = ROOT / name
        if path.is_file():
            yield path
        elif path.is_dir():
            for file in sorted(path.rglob("*")):
                if file.is_file() and file.suffix in TEXT_SUFFIXES and not SKIPPED_DIRS & set(file.relative_to(ROOT).parts):
                    yield file


def process_word_lines(text: str) -> list[tuple[int, str]]:
    """``(line number, line)`` of every line that uses a process word outside the allowed API names."""
    hits = []
    for number, line in enumerate(text.splitlines(), 1):
        if PROCESS_WORDS.search(ALLOWED.sub("", line)):
            hits.append((number, line.strip()))
    return hits


def test_the_pattern_catches_process_words_and_allows_api_names():
    assert process_word_lines(f"measured in {SESS} 12")
    assert process_word_lines(f"see {ISS.title()} #16.7")
    assert process_word_lines(f"no GPU was {LNT}")
    assert process_word_lines("done in this turn")
    assert not process_word_lines(f'@pytest.fixture(scope="{SESS}")')
    assert not process_word_lines("turn the knob by 1.5 rad; the turn about x")


def test_no_process_words_in_the_product():
    this_file = Path(__file__).resolve()
    found = []
    for path in product_files():
        if path.resolve() == this_file:  # the pattern's own examples
            continue
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue
        found += [f"{path.relative_to(ROOT)}:{n}: {line}" for n, line in process_word_lines(text)]
    assert not found, "process words in the product:\n" + "\n".join(found)
