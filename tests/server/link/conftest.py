"""The link tests' own fixture: the simulated grounds a test made are closed after it."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.server.link.simulated import close_grounds


@pytest.fixture(autouse=True)
def _close_simulated_grounds() -> Iterator[None]:
    yield
    close_grounds()
