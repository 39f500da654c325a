"""The Python blocks of the README and of the getting-started page run as a reader would paste
them: in order, in one namespace.

A block whose first line is ``# needs: a, b`` imports optional packages (the ``clients`` extra:
torch-based clients); it runs under ``make examples`` (``CHARGAX_CLIENT_EXAMPLES=1``) where
they are installed, and is skipped otherwise.
"""

from __future__ import annotations

import importlib.util
import os
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
NEEDS = re.compile(r"#\s*needs:\s*(.+)")
CLIENT_EXAMPLES = bool(os.environ.get("CHARGAX_CLIENT_EXAMPLES"))


def python_blocks(text: str) -> list[tuple[int, str]]:
    """``(line, code)`` of every fenced ``python`` block of a Markdown text (line: 1-based,
    the opening fence's)."""
    blocks, code, start = [], None, 0
    for i, line in enumerate(text.splitlines(), 1):
        fence = line.strip()
        if code is None and fence == "```python":
            code, start = [], i
        elif code is not None and fence == "```":
            blocks.append((start, "\n".join(code) + "\n"))
            code = None
        elif code is not None:
            code.append(line)
    if code is not None:
        raise ValueError(f"the python block opened on line {start} is not closed")
    return blocks


def needs(code: str) -> list[str]:
    """The optional modules a block's ``# needs:`` first line names (none: ``[]``)."""
    first = code.lstrip().splitlines()[0] if code.strip() else ""
    match = NEEDS.fullmatch(first.strip())
    return [m.strip() for m in match.group(1).split(",")] if match else []


def test_the_block_reader_finds_blocks_and_their_needs():
    text = "a\n```python\nx = 1\n```\n```bash\nls\n```\n```python\n# needs: sb3, ss\ny = 2\n```\n"
    blocks = python_blocks(text)
    assert blocks == [(2, "x = 1\n"), (8, "# needs: sb3, ss\ny = 2\n")]
    assert needs(blocks[0][1]) == [] and needs(blocks[1][1]) == ["sb3", "ss"]
    with pytest.raises(ValueError, match="line 2 is not closed"):
        python_blocks("a\n```python\nx = 1\n")


def run_blocks(path: Path) -> dict:
    """Run every python block of a Markdown page in order in one namespace, as a reader pastes
    them (a ``# needs:`` block only under ``make examples``); returns the namespace."""
    namespace: dict = {"__name__": path.stem}
    ran, skipped = [], []
    for line, code in python_blocks(path.read_text()):
        missing = [m for m in needs(code) if importlib.util.find_spec(m) is None]
        if needs(code) and (not CLIENT_EXAMPLES or missing):
            skipped.append((line, missing or "run by `make examples`"))
            continue
        try:
            exec(compile(code, f"{path.name}:{line}", "exec"), namespace)
        except Exception as exc:
            raise AssertionError(f"{path.name}'s block on line {line} fails: {exc!r}") from exc
        ran.append(line)
    assert ran, skipped
    return namespace


def test_every_python_block_of_the_readme_runs():
    assert len(python_blocks(README.read_text())) >= 5  # the quick starts, clients, benchmark
    namespace = run_blocks(README)
    # what the blocks left behind: a stepped env of each view and a benchmark score
    assert "profit_eur" in namespace["info"] and "__all__" in namespace["dones"]
    assert namespace["result"]["score"] == pytest.approx(0.0, abs=1e-6)  # always-max scores 0


def test_every_python_block_of_the_getting_started_page_runs():
    namespace = run_blocks(ROOT / "docs" / "getting-started.md")
    assert "profit_eur" in namespace["info"] and "__all__" in namespace["dones"]
    result = namespace["result"]
    assert result["score"] == pytest.approx(
        namespace["get_normalized_score"]("Chargax-shopping-v1", result["daily_profit"])
    )
