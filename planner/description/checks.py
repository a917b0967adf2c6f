"""A description's faults and the small validators that raise them, one file at a time."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from planner.errors import InvalidInput

__all__ = ["NAME", "WHEEL_NAMES", "Checker", "InvalidRobotDescription", "frozen"]

Array = NDArray[np.float64]

#: A robot's, a pose's or an arm link's name.
NAME = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
#: The wheels, in the order of a description's [[wheels]]: the MuJoCo names planner.state
#: expects, so no arm link may take them.
WHEEL_NAMES = ("wheel_x", "wheel_y", "wheel_z")


class InvalidRobotDescription(InvalidInput):
    """A robot description (TOML or URDF) that cannot be loaded: ``file: element: problem``."""

    def __init__(self, path: Path | str, element: str, problem: str) -> None:
        self.path = str(path)
        self.element = element
        self.problem = problem
        super().__init__(f"{path}: {element}: {problem}")


class Checker:
    """Raises :class:`InvalidRobotDescription` for one file."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, element: str, problem: str) -> InvalidRobotDescription:
        return InvalidRobotDescription(self.path, element, problem)

    def number(self, element: str, value: object, *, positive: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(element, f"must be a number, got {value!r}")
        out = float(value)
        if not math.isfinite(out):
            raise self.fail(element, f"must be finite, got {value!r}")
        if positive and out <= 0.0:
            raise self.fail(element, f"must be > 0, got {value!r}")
        return out

    def non_negative(self, element: str, value: object) -> float:
        out = self.number(element, value)
        if out < 0.0:
            raise self.fail(element, f"must be >= 0, got {value!r}")
        return out

    def numbers(self, element: str, value: object, count: int) -> Array:
        if not isinstance(value, list) or len(value) != count:
            raise self.fail(element, f"must be a list of {count} numbers, got {value!r}")
        return np.array([self.number(f"{element}[{i}]", v) for i, v in enumerate(value)])

    def table(self, element: str, value: object) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(element, f"must be a table, got {value!r}")
        return value

    def keys(self, element: str, table: Mapping[str, object], known: frozenset[str]) -> None:
        unknown = sorted(set(table) - known)
        if unknown:
            raise self.fail(
                element, f"unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}"
            )

    def text(self, element: str, value: object) -> str:
        if not isinstance(value, str):
            raise self.fail(element, f"must be a string, got {value!r}")
        return value


def frozen(a: Array) -> Array:
    out = np.array(a, dtype=np.float64)
    out.setflags(write=False)
    return out
