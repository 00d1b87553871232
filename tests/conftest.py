"""Test configuration: make tests/helpers.py importable and expose the repository root."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))


@pytest.fixture
def root() -> Path:
    """The repository root (configs/, docs/ live there)."""
    return ROOT
