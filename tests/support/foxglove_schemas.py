"""Foxglove's message schemas as the tests check our messages against them: restated from
foxglove-sdk's jsonschema files and closed (``additionalProperties: false``), so that a
misspelt or extra field fails even where Foxglove's own schema would let it pass."""

from __future__ import annotations

from typing import Any


def _closed(properties: dict[str, Any]) -> dict[str, Any]:
    """An object of exactly ``properties``, every one required, no other."""
    return {
        "type": "object",
        "additionalProperties": False,
        "required": list(properties),
        "properties": properties,
    }


def _numbers(keys: str) -> dict[str, Any]:
    return _closed({k: {"type": "number"} for k in keys})


_STRING = {"type": "string"}
_TIME = _closed(
    {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
    }
)

# foxglove-sdk schemas/jsonschema/FrameTransforms.json
FOXGLOVE_FRAME_TRANSFORMS = _closed(
    {
        "transforms": {
            "type": "array",
            "items": _closed(
                {
                    "timestamp": _TIME,
                    "parent_frame_id": _STRING,
                    "child_frame_id": _STRING,
                    "translation": _numbers("xyz"),
                    "rotation": _numbers("xyzw"),
                }
            ),
        }
    }
)

# foxglove-sdk schemas/jsonschema/Log.json
FOXGLOVE_LOG = _closed(
    {
        "timestamp": _TIME,
        "level": {"enum": [0, 1, 2, 3, 4, 5]},
        "message": _STRING,
        "name": _STRING,
        "file": _STRING,
        "line": {"type": "integer", "minimum": 0, "maximum": 4294967295},
    }
)
