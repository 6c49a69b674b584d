"""Where the tests find the repository's own files (``data/``, ``docs/``, ``scripts/``, the README, the Rust
sources, the pinned outputs), whichever folder of ``tests/`` a test lives in."""

from pathlib import Path

#: The repository's root (the folder holding ``pyproject.toml``).
REPO = Path(__file__).resolve().parents[2]
#: The pinned numerical outputs and the script that makes them (tests/compensation/test_pinned_outputs.py).
PINNED = Path(__file__).resolve().parent / "pinned"
