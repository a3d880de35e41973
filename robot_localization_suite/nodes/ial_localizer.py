"""``ial_localizer``: the shared localizer node running the ``ial_localizer`` plugin, with its boxes on ``~/boxes``."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

from ..registry import PLUGINS
from ..ros.extras import IAL_BOXES
from .localizer_node import LocalizerNode, run_localizer


def create_node(**options: Any) -> LocalizerNode:
    """The node, for a container (``nodes/container.py``): ``options`` go to rclpy's ``Node``."""
    return LocalizerNode(PLUGINS["ial_localizer"], extras=IAL_BOXES, **options)


def main(argv: Sequence[str] | None = None) -> int:
    return run_localizer(PLUGINS["ial_localizer"], argv, extras=IAL_BOXES)


if __name__ == "__main__":
    sys.exit(main())
