"""The one exception type every splat file reader and writer raises."""

from __future__ import annotations

import os


class SplatFileError(ValueError):
    """A splat file could not be read or written; the message names the file and the problem."""

    def __init__(self, path: str | os.PathLike, problem: str) -> None:
        super().__init__(f"{os.fspath(path)}: {problem}")
        self.path = os.fspath(path)
        self.problem = problem
