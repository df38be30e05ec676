"""firetrack's algorithms: pure numpy/scipy in, numbers out (no network, files or clocks).

Loaders for real recording formats live at the edge, in :mod:`pdr.io`.
"""

from pdr.kernel_cache import configure as _configure_kernel_cache

_configure_kernel_cache()
