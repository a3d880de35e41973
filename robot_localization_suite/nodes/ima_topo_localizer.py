"""``ima_topo_localizer``: the shared localizer node running the camera plugin, with the place name on ``~/place``."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

from ..registry import PLUGINS
from ..ros.extras import IMA_PLACE
from .localizer_node import LocalizerNode, run_localizer


def create_node(**options: Any) -> LocalizerNode:
    """The node, for a container (``nodes/container.py``): ``options`` go to rclpy's ``Node``."""
    return LocalizerNode(PLUGINS["ima_topo_localizer"], extras=IMA_PLACE, **options)


def main(argv: Sequence[str] | None = None) -> int:
    return run_localizer(PLUGINS["ima_topo_localizer"], argv, extras=IMA_PLACE)


if __name__ == "__main__":
    sys.exit(main())
