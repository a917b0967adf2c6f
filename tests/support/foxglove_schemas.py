"""Foxglove's message schemas as the tests check our messages against them: restated from
foxglove-sdk's jsonschema files and closed (``additionalProperties: false``), so that a
misspelt or extra field fails even where Foxglove's own schema would let it pass."""

from __future__ import annotations

# Foxglove's published foxglove.FrameTransforms, restated field by field (and closed with
# additionalProperties: false so a misspelt or extra field fails here even where Foxglove's
# own schema would let it pass).
_XYZ = {k: {"type": "number"} for k in "xyz"}


FOXGLOVE_FRAME_TRANSFORMS = {
    "type": "object",
    "required": ["transforms"],
    "additionalProperties": False,
    "properties": {
        "transforms": {
            "type": "array",
            "items": {
                "type": "object",
                "additionalProperties": False,
                "required": [
                    "timestamp",
                    "parent_frame_id",
                    "child_frame_id",
                    "translation",
                    "rotation",
                ],
                "properties": {
                    "timestamp": {
                        "type": "object",
                        "additionalProperties": False,
                        "required": ["sec", "nsec"],
                        "properties": {
                            "sec": {"type": "integer", "minimum": 0},
                            "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
                        },
                    },
                    "parent_frame_id": {"type": "string"},
                    "child_frame_id": {"type": "string"},
                    "translation": {
                        "type": "object",
                        "additionalProperties": False,
                        "required": ["x", "y", "z"],
                        "properties": _XYZ,
                    },
                    "rotation": {
                        "type": "object",
                        "additionalProperties": False,
                        "required": ["x", "y", "z", "w"],
                        "properties": _XYZ | {"w": {"type": "number"}},
                    },
                },
            },
        }
    },
}


# foxglove-sdk schemas/jsonschema/Log.json, restated and closed (additionalProperties false).
FOXGLOVE_LOG = {
    "type": "object",
    "additionalProperties": False,
    "required": ["timestamp", "level", "message", "name", "file", "line"],
    "properties": {
        "timestamp": {
            "type": "object",
            "additionalProperties": False,
            "required": ["sec", "nsec"],
            "properties": {
                "sec": {"type": "integer", "minimum": 0},
                "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
            },
        },
        "level": {"enum": [0, 1, 2, 3, 4, 5]},
        "message": {"type": "string"},
        "name": {"type": "string"},
        "file": {"type": "string"},
        "line": {"type": "integer", "minimum": 0, "maximum": 4294967295},
    },
}
