"""``hybrid_localizer``: the shared localizer node running the ``hybrid_localizer`` plugin of ``registry.PLUGINS``."""

from __future__ import annotations

import sys
from collections.abc import Sequence

from ..registry import PLUGINS
from .localizer_node import run_localizer


def main(argv: Sequence[str] | None = None) -> int:
    return run_localizer(PLUGINS["hybrid_localizer"], argv)


if __name__ == "__main__":
    sys.exit(main())
