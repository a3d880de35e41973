"""``python -m robot_localization_suite.tools.soak``: the ``rls_soak`` command."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
