"""JSON documents inside splat files (SOG meta.json, lod-meta.json, glTF): parsed to an object
or a SplatFileError naming the file.

Nesting is bounded before parsing (`MAX_DEPTH`): Python's parser recurses per level, so a few
kilobytes of `[[[[...` would otherwise end in a RecursionError, or a crash on a thread with a
small stack. The depth is found in linear time: strings are blanked by one regular expression,
then the brackets left are summed by NumPy.
"""

from __future__ import annotations

import contextlib
import json
import re
from pathlib import Path
from typing import Iterator

import numpy as np

from .errors import SplatFileError

__all__ = ["parse_object", "malformed", "nesting_depth", "MAX_DEPTH"]

MAX_DEPTH = 200  # a LOD tree of a million nodes in a balanced binary tree is about 45 deep
_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)
_OPEN = np.zeros(256, np.int8)
_OPEN[[ord("["), ord("{")]] = 1
_OPEN[[ord("]"), ord("}")]] = -1


def nesting_depth(text: bytes) -> int:
    """The deepest bracket nesting of a JSON text (outside strings)."""
    bare = np.frombuffer(_STRING.sub(b'""', bytes(text)), np.uint8)
    steps = _OPEN[bare]
    steps = steps[steps != 0]
    return int(np.cumsum(steps, dtype=np.int64).max(initial=0))


def parse_object(path: Path, text: bytes, what: str) -> dict:
    """`text` as a JSON object; `what` names the document in the error ("meta.json", ...)."""
    depth = nesting_depth(text)
    if depth > MAX_DEPTH:
        raise SplatFileError(path, f"{what} nests {depth} levels deep, more than {MAX_DEPTH}")
    try:
        document = json.loads(text)
    except (ValueError, UnicodeDecodeError) as e:
        raise SplatFileError(path, f"bad JSON in {what}: {e}") from None
    except RecursionError:  # the bound above is under Python's default limit: a net only
        raise SplatFileError(path, f"{what} nests too deeply") from None
    if not isinstance(document, dict):
        raise SplatFileError(path, f"{what} is not a JSON object")
    return document


@contextlib.contextmanager
def malformed(path: Path, what: str) -> Iterator[None]:
    """Turn the errors a document of unexpected shape causes deep inside a reader (a list where
    an object belongs, a string for a number) into a SplatFileError naming the file; the readers'
    own checks come first and say more, this is the net under them. Running out of memory or
    stack becomes a SplatFileError too (its message says so)."""
    try:
        yield
    except SplatFileError:
        raise
    except (TypeError, ValueError, KeyError, AttributeError, IndexError, OverflowError) as e:
        raise SplatFileError(path, f"malformed {what}: {type(e).__name__}: {e}") from None
    except RecursionError:
        raise SplatFileError(path, f"malformed {what}: nested too deeply") from None
    except MemoryError:
        raise SplatFileError(path, f"not enough memory to load this {what}") from None
