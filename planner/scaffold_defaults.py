"""The defaults of a scaffolded robot description (:mod:`planner.description.scaffold`), in
a module of their own that imports nothing: ``hikoboshi robot init`` shows them in its
options at start-up, before (and without) loading the description machinery."""

from __future__ import annotations

__all__ = ["DEFAULT_BASE_MASS_KG", "DEFAULT_BASE_SIZE_M"]

#: The cube the arm sits on where the user gives none: 300 kg, 1 m a side, our choice (the
#: mount the vendor arms' tests use, tests/planner/vendor/*.toml).
DEFAULT_BASE_MASS_KG = 300.0
DEFAULT_BASE_SIZE_M = 1.0
