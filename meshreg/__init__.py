"""meshreg: elastic shape registration of surfaces (DP, gradient descent, Kabsch).

>>> import meshreg
>>> from meshreg.samples import paper_pairs
>>> pair = paper_pairs(21, 21)[6]
>>> result = meshreg.register(pair.first, pair.second, mode="dp")
>>> result.rotation.round().astype(int).tolist()
[[0, 1, 0], [0, 0, 1], [1, 0, 0]]
"""

from importlib import import_module
from importlib.metadata import PackageNotFoundError, version

from .errors import InputError, RunError
from .options import MODES, Advanced, Options

# the heavy parts (numba kernels, scipy) load on first use, so that `meshreg --help` and `import meshreg` are quick
_LAZY = {
    "DistanceMatrix": "batch",
    "distance_matrix": "batch",
    "GridSurface": "grid",
    "read_grid": "grid",
    "register": "pipeline",
    "register_symmetric": "pipeline",
    "register_with": "pipeline",
    "Registration": "result",
    "Atlas": "atlas_result",
    "AtlasSettings": "atlas_settings",
    "atlas": "shape_atlas",
}

__all__ = [
    "MODES",
    "Advanced",
    "Atlas",
    "AtlasSettings",
    "DistanceMatrix",
    "GridSurface",
    "InputError",
    "Options",
    "Registration",
    "RunError",
    "distance_matrix",
    "read_grid",
    "register",
    "register_symmetric",
    "register_with",
]

try:
    __version__ = version("meshreg")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0+unknown"


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'meshreg' has no attribute {name!r}")


def __dir__():
    return __all__
