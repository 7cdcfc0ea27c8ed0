"""The tree passes the ruff configuration of ``pyproject.toml``: pycodestyle errors, pyflakes, import
order and pyupgrade, lines up to 120 characters."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_the_tree_passes_ruff():
    out = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", str(ROOT)], capture_output=True,
                         text=True, cwd=ROOT)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "All checks passed" in out.stdout


def test_ruff_finds_what_it_is_configured_to_find(tmp_path):
    """The check can fail: an unused import, unsorted imports and an old-style annotation are each found."""
    bad = tmp_path / "bad.py"
    bad.write_text("import sys\nimport os\nfrom typing import Optional\n\n\ndef f(x: Optional[int]) -> int:\n"
                   "    return x\n")
    out = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "--config", str(ROOT / "pyproject.toml"),
                          str(bad)], capture_output=True, text=True, cwd=tmp_path)
    assert out.returncode == 1
    assert "F401" in out.stdout and "I001" in out.stdout
    assert "UP045" in out.stdout or "UP007" in out.stdout  # Optional[int] -> int | None (UP007 before ruff 0.8)
