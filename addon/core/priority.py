"""Background work yields to the UI: a training thread at a lower scheduling priority.

Training beside Blender's UI leaves the UI a core (`jobs.ui_kernel_threads`), but on a 2-core
machine that core is shared with the window's redraws: software OpenGL rasterises on every core,
and a redraw racing a training thread of equal priority took 0.2-0.33 s (issue 36). At a lower
priority the training thread takes only the time the UI leaves, and loses little: the UI is
idle most of the time.

`at_background_priority(work)` runs `work` on a thread of its own at a lower priority, where
the OS gives threads their own (Linux: a thread's nice value; Windows: a thread priority; not
macOS), and returns its result here. A thread of its own because a lowered priority cannot be
raised again without privileges, and because threads inherit their creator's: `work` must run
its native kernels on its own thread (one kernel thread), or the native thread pool it starts
would serve every later render at the lowered priority.
"""

from __future__ import annotations

import os
import sys
import threading
from typing import Callable, TypeVar

BACKGROUND_NICE = 10  # Linux: the scheduler's weight falls about 10x from nice 0
_WINDOWS_BELOW_NORMAL = -1  # THREAD_PRIORITY_BELOW_NORMAL
T = TypeVar("T")


def lower_this_thread() -> bool:
    """Lower the calling thread's priority (never raise it); True when the OS took it."""
    try:
        if sys.platform.startswith("linux"):
            tid = threading.get_native_id()
            nice = os.getpriority(os.PRIO_PROCESS, tid)
            if nice < BACKGROUND_NICE:
                os.setpriority(os.PRIO_PROCESS, tid, BACKGROUND_NICE)
            return True
        if sys.platform == "win32":
            import ctypes
            kernel32 = ctypes.WinDLL("kernel32")
            return bool(kernel32.SetThreadPriority(kernel32.GetCurrentThread(),
                                                   _WINDOWS_BELOW_NORMAL))
    except (OSError, AttributeError):
        pass  # a sandbox that refuses it: the thread runs at the priority it had
    return False


def at_background_priority(work: Callable[[], T]) -> T:
    """`work()` on a new thread at a lowered priority; its result, or its exception, here."""
    outcome: dict[str, object] = {}

    def run() -> None:
        lower_this_thread()
        try:
            outcome["result"] = work()
        except BaseException as error:  # re-raised on the caller's thread
            outcome["error"] = error

    thread = threading.Thread(target=run, name=threading.current_thread().name + " (background)",
                              daemon=True)
    thread.start()
    thread.join()
    if "error" in outcome:
        raise outcome["error"]  # type: ignore[misc]
    return outcome["result"]  # type: ignore[return-value]
