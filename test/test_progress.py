"""Progress reporting of long precomputation (core/progress.py): what another thread reads while a bar runs."""

from __future__ import annotations

import threading

from robot_localization_suite.core import progress
from robot_localization_suite.core.progress import ReportingBar, current_progress


def test_closing_a_bar_leaves_the_other_bars_open_even_at_the_same_position() -> None:
    # tqdm compares bars by screen position: a disabled bar and another can compare equal.
    outer = ReportingBar(total=4, disable=True)
    inner = ReportingBar(total=2, disable=True)
    outer.update(1)
    inner.update(1)
    assert current_progress() == 0.375  # one outer step of four done, half of the next
    inner.close()
    assert current_progress() == 0.25
    outer.close()
    assert current_progress() is None


def test_a_bar_closed_while_its_thread_holds_the_registry_does_not_wait_on_itself() -> None:
    # tqdm closes a bar from __del__, which the garbage collector may run inside another bar's close.
    done = threading.Event()

    def close_inside() -> None:
        bar = ReportingBar(total=1, disable=True)
        with progress._LOCK:
            bar.close()
        done.set()

    worker = threading.Thread(target=close_inside, daemon=True)
    worker.start()
    worker.join(30)
    assert done.is_set()
