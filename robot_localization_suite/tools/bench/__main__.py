"""``python -m robot_localization_suite.tools.bench``: the ``rls_bench`` command."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
