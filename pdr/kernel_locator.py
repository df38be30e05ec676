"""Where numba files a ``pdr`` kernel inside the cache folder: by the file's place in the package.

numba's locator for ``NUMBA_CACHE_DIR`` names a file's subfolder by a hash of its absolute
directory, so the same sources in another checkout (a fresh clone, a worktree, CI) are
compiled again. The folder :mod:`pdr.kernel_cache` chose is already named by a hash of every
kernel source and what they import, so the package-relative path is enough to tell files apart;
numba's own stamp still checks each defining file's bytes before it loads anything.

Imported by numba itself (``NUMBA_CACHE_LOCATOR_CLASSES``), never by the package.
"""
from __future__ import annotations

import os
from pathlib import Path

from numba.core import caching, config

from pdr.kernel_cache import _PACKAGE


class PackageCacheLocator(caching.UserProvidedCacheLocator):
    """numba's ``NUMBA_CACHE_DIR`` locator, with ``<CACHE_DIR>/pdr/<folder in pdr>`` as the path;
    for files outside this checkout's ``pdr`` it declines (numba's next locator takes them)."""

    def __init__(self, py_func, py_file):
        super().__init__(py_func, py_file)
        inside = Path(py_file).resolve().parent.relative_to(_PACKAGE)
        self._cache_path = os.path.join(config.CACHE_DIR, _PACKAGE.name, *inside.parts)

    @classmethod
    def from_function(cls, py_func, py_file):
        if not Path(py_file).resolve().is_relative_to(_PACKAGE):
            return None
        return super().from_function(py_func, py_file)
