"""``mcl_baseline``: the shared localizer node running the ``mcl_baseline`` plugin of ``registry.PLUGINS``."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

from ..registry import PLUGINS
from .localizer_node import LocalizerNode, run_localizer


def create_node(**options: Any) -> LocalizerNode:
    """The node, for a container (``nodes/container.py``): ``options`` go to rclpy's ``Node``."""
    return LocalizerNode(PLUGINS["mcl_baseline"], **options)


def main(argv: Sequence[str] | None = None) -> int:
    return run_localizer(PLUGINS["mcl_baseline"], argv)


if __name__ == "__main__":
    sys.exit(main())
