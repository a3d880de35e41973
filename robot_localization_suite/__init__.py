"""robot_localization_suite: five published localization methods and a simulator, side by side.

numba writes its compiled kernels (``cache=True``) under the package's cache directory
(``$RLS_CACHE_DIR`` or ``~/.cache/robot_localization_suite``, in ``numba/``), never into the
source or install tree; an explicit ``$NUMBA_CACHE_DIR`` still wins.
"""

import os

from .core.cache import default_cache_dir

__version__ = "0.1.0"

os.environ.setdefault("NUMBA_CACHE_DIR", str(default_cache_dir() / "numba"))
