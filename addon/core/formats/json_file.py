"""JSON documents inside splat files (SOG meta.json, lod-meta.json, glTF): parsed to an object
or a SplatFileError naming the file."""

from __future__ import annotations

import json
from pathlib import Path

from .errors import SplatFileError

__all__ = ["parse_object"]


def parse_object(path: Path, text: bytes, what: str) -> dict:
    """`text` as a JSON object; `what` names the document in the error ("meta.json", ...)."""
    try:
        document = json.loads(text)
    except (ValueError, UnicodeDecodeError) as e:
        raise SplatFileError(path, f"bad JSON in {what}: {e}") from None
    if not isinstance(document, dict):
        raise SplatFileError(path, f"{what} is not a JSON object")
    return document
