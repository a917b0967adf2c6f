"""The type of the ``made_once`` fixture (tests/conftest.py), for the modules that take it."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

#: ``made_once(name, make)``: the folder ``name`` that ``make(folder)`` fills (a costly
#: product several modules read, such as a vendor arm's ``robot init``).
MadeOnce = Callable[[str, Callable[[Path], None]], Path]
