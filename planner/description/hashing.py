"""A description's content hash: its canonical TOML (without the URDF's file name) and its
canonical URDF, so that comments, layout and the URDF's file name do not change it."""

from __future__ import annotations

import hashlib
import json
import xml.etree.ElementTree as ET
from collections.abc import Iterator, Mapping
from typing import Any

__all__ = ["canonical_toml", "canonical_xml", "content_sha256"]


def content_sha256(doc: Mapping[str, Any], urdf_root: ET.Element) -> str:
    """``RobotDescription.content_sha256``: the parsed TOML and the parsed URDF's root."""
    return hashlib.sha256(
        b"hikoboshi-robot/1\0" + canonical_toml(doc) + b"\0" + canonical_xml(urdf_root)
    ).hexdigest()


def canonical_xml(root: ET.Element) -> bytes:
    """The parsed document (comments already dropped) as JSON events: each element's tag,
    sorted attributes and stripped text, its children, then its stripped tail. Iterative, so
    a deeply nested file cannot exhaust the stack, and linear (C14N in Python is not)."""
    out: list[object] = []
    stack: list[tuple[ET.Element, Iterator[ET.Element]]] = []

    def start(elem: ET.Element) -> None:
        out.append([elem.tag, sorted(elem.attrib.items()), (elem.text or "").strip()])
        stack.append((elem, iter(elem)))

    start(root)
    while stack:
        elem, children = stack[-1]
        child = next(children, None)
        if child is None:
            stack.pop()
            out.append(["/", (elem.tail or "").strip() if stack else ""])
        else:
            start(child)
    return json.dumps(out, separators=(",", ":"), ensure_ascii=False).encode()


def canonical_toml(doc: Mapping[str, Any]) -> bytes:
    def other(value: object) -> object:
        if hasattr(value, "isoformat"):
            return {"toml-datetime": value.isoformat()}
        raise TypeError(type(value).__name__)

    content = {k: v for k, v in doc.items() if k != "urdf"}  # content, not the file's name
    return json.dumps(
        content, sort_keys=True, separators=(",", ":"), ensure_ascii=False, default=other
    ).encode()
