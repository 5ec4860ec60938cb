"""The one rule for the add-on's thread counts (addon/core/threads.py; named apart from
tests/core/render/test_threads.py, which pytest would take for the same module)."""

from __future__ import annotations

import pytest

from addon.core.threads import kernel_threads


def test_the_setting_then_blenders_render_threads_then_every_core():
    assert kernel_threads(5, 3, cores=16) == 5
    assert kernel_threads(0, 3, cores=16) == 3
    assert kernel_threads(0, 0, cores=16) == 16


def test_beside_the_ui_every_core_but_one():
    assert kernel_threads(0, 0, beside_ui=True, cores=16) == 15
    assert kernel_threads(0, 16, beside_ui=True, cores=16) == 15
    assert kernel_threads(4, 16, beside_ui=True, cores=16) == 4
    assert kernel_threads(32, 0, beside_ui=True, cores=16) == 15
    assert kernel_threads(0, 0, beside_ui=True, cores=1) == 1  # never none
    assert kernel_threads(0, 0, beside_ui=False, cores=1) == 1


def test_this_machines_cores_by_default():
    from addon.core.native import cpu_count

    assert kernel_threads() == cpu_count()
    assert kernel_threads(beside_ui=True) == max(1, cpu_count() - 1)


def test_negative_counts_are_refused():
    with pytest.raises(ValueError):
        kernel_threads(-1)
    with pytest.raises(ValueError):
        kernel_threads(0, -2)
