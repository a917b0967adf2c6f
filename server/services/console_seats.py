"""Seats for consoles: how many console websockets one token holder and one address may
hold at once (docs/console.md "Connection caps", docs/security.md "Console caps").

A console is admitted after it has authenticated and before the hub takes it
(:mod:`server.api.console`); over a cap it is refused with the reason and never reaches the
hub. Two caps:

- ``per_token``: consoles of one token holder (its ``name``), whatever the role and the
  address: one leaked or shared token cannot hold every console.
- ``per_address``: *viewers'* consoles from one client address. An operator's consoles
  are not counted here and not refused here (only by their own per-token cap), so that any
  number of viewers at the operator's address (a control room behind one NAT) can never
  keep the operator out.

Used from the event loop only (no lock). A seat is given back when its console ends, on
every path (a ``with`` block).
"""

from __future__ import annotations

from collections import Counter
from types import TracebackType

__all__ = ["ConsoleRefused", "ConsoleSeat", "ConsoleSeats"]


class ConsoleRefused(Exception):
    """A console over a cap: ``cap`` names it (``per_token``, ``per_address``)."""

    def __init__(self, cap: str, message: str) -> None:
        super().__init__(message)
        self.cap = cap
        self.message = message


class ConsoleSeats:
    """The consoles held, by token holder and by address (viewers only), against the caps."""

    def __init__(self, *, per_token: int, per_address: int) -> None:
        if per_token < 1 or per_address < 1:
            raise ValueError(f"caps per token {per_token} and per address {per_address} < 1")
        self.per_token = per_token
        self.per_address = per_address
        self.by_token: Counter[str] = Counter()
        self.by_address: Counter[str] = Counter()

    def take(self, *, holder: str, address: str, operator: bool) -> ConsoleSeat:
        """A seat for a console of ``holder`` from ``address``; :class:`ConsoleRefused`
        when a cap is reached (nothing taken)."""
        if self.by_token[holder] >= self.per_token:
            raise ConsoleRefused(
                "per_token",
                f"token holder {holder!r} already has {self.by_token[holder]} consoles "
                f"(consoles_per_token {self.per_token})",
            )
        if not operator and self.by_address[address] >= self.per_address:
            raise ConsoleRefused(
                "per_address",
                f"address {address} already has {self.by_address[address]} viewer consoles "
                f"(consoles_per_address {self.per_address})",
            )
        self.by_token[holder] += 1
        if not operator:
            self.by_address[address] += 1
        return ConsoleSeat(self, holder, None if operator else address)

    def _give_back(self, holder: str, address: str | None) -> None:
        self.by_token[holder] -= 1
        if self.by_token[holder] <= 0:
            del self.by_token[holder]
        if address is not None:
            self.by_address[address] -= 1
            if self.by_address[address] <= 0:
                del self.by_address[address]


class ConsoleSeat:
    """One console's seat: given back once, when its ``with`` block ends."""

    def __init__(self, seats: ConsoleSeats, holder: str, address: str | None) -> None:
        self._seats: ConsoleSeats | None = seats
        self._holder = holder
        self._address = address

    def __enter__(self) -> ConsoleSeat:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.release()

    def release(self) -> None:
        if self._seats is not None:
            self._seats._give_back(self._holder, self._address)
            self._seats = None
