"""The reconstruction in a process of its own, for Blender's operator.

In its own process the reconstruction leaves Blender's interface free, stops the moment the
user cancels (the process is ended: every stage writes its files atomically, so the next run
resumes), a crash in it cannot take Blender (and the user's unsaved work) with it, and it runs
in a Blender that cannot load pycolmap itself. The child is the `reconstruct` command-line verb
with `--json` (`core.child`: the same Python and module path as Blender's).

    process = ReconstructionProcess(source, folder, {"threads": 2})
    while process.running:
        print(process.step)        # the newest `Step` as JSON (stage, line, fraction), or None
    report = process.report()      # the Report as JSON, or ReconstructionError with the reason
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from collections import deque

from ..child import environment, python_command
from .errors import ReconstructionError

STOP_GRACE = 5.0  # seconds between asking the child to end and killing it


def command(source: str | os.PathLike, folder: str | os.PathLike, options: dict) -> list[str]:
    args = ["reconstruct", str(source), "--out", str(folder), "--json"]
    for name, value in options.items():
        args += [f"--{name.replace('_', '-')}", str(value)]
    return python_command("cli", args)


def peak_memory_mb() -> float | None:
    """This process's peak resident memory since it started its program, in MB (Linux's
    VmHWM; `getrusage` would also count what a forked parent had resident before the exec)."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


class ReconstructionProcess:
    """The child process and what it has said so far (read on two daemon threads)."""

    def __init__(self, source, folder, options: dict | None = None) -> None:
        flags = getattr(subprocess, "CREATE_NO_WINDOW", 0)  # Windows: no console window
        try:
            self._process = subprocess.Popen(
                command(source, folder, options or {}), stdout=subprocess.PIPE,
                stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, env=environment(),
                encoding="utf-8", errors="replace", creationflags=flags)
        except OSError as error:
            raise ReconstructionError(f"cannot start the reconstruction process "
                                      f"({sys.executable}): {error}") from None
        self.step: dict | None = None
        self._report: dict | None = None
        self._errors: deque[str] = deque(maxlen=40)
        self._readers = [threading.Thread(target=self._read_stdout, daemon=True),
                         threading.Thread(target=self._read_stderr, daemon=True)]
        for reader in self._readers:
            reader.start()

    def _read_stdout(self) -> None:
        for line in self._process.stdout:
            try:
                message = json.loads(line)
            except ValueError:
                continue  # a library's own print: not ours
            if isinstance(message, dict) and "step" in message:
                self.step = message["step"]
            elif isinstance(message, dict) and "report" in message:
                self._report = message["report"]

    def _read_stderr(self) -> None:
        for line in self._process.stderr:
            if line.strip():
                self._errors.append(line.rstrip())

    @property
    def running(self) -> bool:
        return self._process.poll() is None or any(r.is_alive() for r in self._readers)

    def wait(self, timeout: float | None = None) -> int | None:
        try:
            code = self._process.wait(timeout)
        except subprocess.TimeoutExpired:
            return None
        for reader in self._readers:
            reader.join(timeout)
        return code

    def stop(self) -> None:
        """End the child now (cancelling): politely, then by force."""
        if self._process.poll() is None:
            self._process.terminate()
            if self.wait(STOP_GRACE) is None:
                self._process.kill()
                self.wait()

    def report(self) -> dict:
        """The finished run's report; ReconstructionError with the child's reason otherwise."""
        code = self.wait()
        if code == 0 and self._report is not None:
            return self._report
        lines = list(self._errors)
        starts = [k for k, line in enumerate(lines) if " reconstruct: error: " in line]
        if starts:  # the verb's own message, with any lines that continue it
            first = starts[-1]
            reason = [lines[first].split(" error: ", 1)[1]] + lines[first + 1:]
            raise ReconstructionError("\n".join(reason))
        tail = "\n".join(lines[-8:])
        raise ReconstructionError(f"the reconstruction process ended with status {code}"
                                  + (f":\n{tail}" if tail else ""))
