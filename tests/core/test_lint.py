"""The linter as a test: ruff check and ruff format pass on every Python file of the repository.

ruff.toml holds the rules: pycodestyle, pyflakes, import sorting, lines of at most 100 columns."""

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
RUFF = [sys.executable, "-m", "ruff"]


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*RUFF, *args], cwd=REPO, capture_output=True, text=True, timeout=300)


def test_ruff_finds_nothing() -> None:
    result = run("check", "--no-cache", "--output-format", "concise", ".")
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]


def test_every_file_is_formatted() -> None:
    result = run("format", "--no-cache", "--check", ".")
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]


def test_the_linter_sees_a_long_line_and_unsorted_imports(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text("import sys\nimport os\n\nX = '" + "x" * 100 + "'\n")
    result = subprocess.run(
        [*RUFF, "check", "--no-cache", "--config", str(REPO / "ruff.toml"), str(bad)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert "E501" in result.stdout and "I001" in result.stdout, result.stdout
