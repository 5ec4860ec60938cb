"""JSON documents inside splat files (SOG meta.json, lod-meta.json, glTF): parsed to an object
or a SplatFileError naming the file."""

from __future__ import annotations

import contextlib
import json
from pathlib import Path
from typing import Iterator

from .errors import SplatFileError

__all__ = ["parse_object", "malformed"]


def parse_object(path: Path, text: bytes, what: str) -> dict:
    """`text` as a JSON object; `what` names the document in the error ("meta.json", ...)."""
    try:
        document = json.loads(text)
    except (ValueError, UnicodeDecodeError) as e:
        raise SplatFileError(path, f"bad JSON in {what}: {e}") from None
    if not isinstance(document, dict):
        raise SplatFileError(path, f"{what} is not a JSON object")
    return document


@contextlib.contextmanager
def malformed(path: Path, what: str) -> Iterator[None]:
    """Turn the errors a document of unexpected shape causes deep inside a reader (a list where
    an object belongs, a string for a number) into a SplatFileError naming the file; the readers'
    own checks come first and say more, this is the net under them."""
    try:
        yield
    except SplatFileError:
        raise
    except (TypeError, ValueError, KeyError, AttributeError, IndexError, OverflowError) as e:
        raise SplatFileError(path, f"malformed {what}: {type(e).__name__}: {e}") from None
