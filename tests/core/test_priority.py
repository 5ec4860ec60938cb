"""Background work at a lower priority (addon/core/priority.py): the work runs lowered where the
OS allows it, the caller keeps its own priority, results and errors come back."""

from __future__ import annotations

import os
import sys
import threading

import pytest

from addon.core.priority import BACKGROUND_NICE, at_background_priority

linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread nice: Linux")


def _nice() -> int:
    return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())


def test_the_result_and_the_error_come_back_to_the_caller() -> None:
    assert at_background_priority(lambda: 42) == 42

    def fails() -> None:
        raise ValueError("from the background")

    with pytest.raises(ValueError, match="from the background"):
        at_background_priority(fails)


@linux
def test_the_work_runs_lowered_and_the_caller_is_not() -> None:
    before = _nice()
    ran_on: list[int] = []
    seen = at_background_priority(lambda: (ran_on.append(threading.get_native_id()), _nice())[1])
    assert seen == max(before, BACKGROUND_NICE)
    assert ran_on[0] != threading.get_native_id()  # a thread of its own
    assert _nice() == before  # lowering cannot be undone, so the caller is never lowered
