"""The console command's start-up: NumPy's tool submodules that SciPy touches at import but meshreg never uses are
loaded when first used instead (:func:`defer_numpy_tools`).

SciPy 1.17 builds its array-API namespace with ``dir(numpy)`` and ``getattr`` on every name
(``scipy._lib.array_api_compat.numpy``), and NumPy 2 imports its lazy submodules on that ``getattr``:
``numpy.f2py`` (with ``charset_normalizer``: 0.068 s), ``numpy.ma`` (0.019 s) and ``numpy.testing`` (0.009 s),
measured with ``python -X importtime`` inside ``meshreg register``. Each is imported as a module
that loads itself at its first attribute access (:class:`importlib.util.LazyLoader`, the recipe of the Python
documentation), so code that uses them gets the real module. ``import scipy.sparse`` after NumPy took 0.05-0.07 s
with this against 0.15-0.18 s without (three alternations, fresh processes).

Only :func:`meshreg.cli.run` calls it: a library should not change how its caller's NumPy loads.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import importlib.util
import sys

# NumPy's submodules that SciPy's import touches and meshreg's work does not use
DEFERRED = ("numpy.f2py", "numpy.ma", "numpy.testing")


class _Deferring(importlib.abc.MetaPathFinder):
    """Finds the modules ``names`` as the standard path finder does, with a loader that defers their execution."""

    def __init__(self, names: tuple[str, ...]):
        self.names = frozenset(names)

    def find_spec(self, name, path, target=None):
        if name not in self.names:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path, target)
        if spec is not None and spec.loader is not None:
            spec.loader = importlib.util.LazyLoader(spec.loader)
        return spec


def defer_numpy_tools(names: tuple[str, ...] = DEFERRED) -> None:
    """Have each of ``names`` (submodules of NumPy), when it is imported, made a module that loads itself when one
    of its attributes is first used; what is already imported stays as it is. Imports nothing itself (``meshreg
    --help`` does not import NumPy)."""
    if not any(isinstance(finder, _Deferring) for finder in sys.meta_path):
        sys.meta_path.insert(0, _Deferring(names))
