"""``ial_localizer``: the shared localizer node running the ``ial_localizer`` plugin, with its boxes on ``~/boxes``."""

from __future__ import annotations

import sys
from collections.abc import Sequence

from ..registry import PLUGINS
from ..ros.extras import IAL_BOXES
from .localizer_node import run_localizer


def main(argv: Sequence[str] | None = None) -> int:
    return run_localizer(PLUGINS["ial_localizer"], argv, extras=IAL_BOXES)


if __name__ == "__main__":
    sys.exit(main())
