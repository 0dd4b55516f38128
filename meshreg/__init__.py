"""meshreg: elastic shape registration of surfaces (DP, gradient descent, Kabsch).

>>> import meshreg
>>> from meshreg.samples import paper_pairs
>>> pair = paper_pairs(21, 21)[6]
>>> result = meshreg.register(pair.first, pair.second, mode="dp")
>>> result.rotation.round().astype(int).tolist()
[[0, 1, 0], [0, 0, 1], [1, 0, 0]]
"""

from .batch import DistanceMatrix, distance_matrix
from .errors import InputError, RunError
from .grid import GridSurface, read_grid
from .options import MODES, Advanced, Options
from .register import register, register_symmetric, register_with
from .result import Registration

__all__ = [
    "MODES",
    "Advanced",
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
__version__ = "0.1.0"
