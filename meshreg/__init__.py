"""meshreg: elastic shape registration of surfaces (DP, gradient descent, Kabsch).

>>> import meshreg
>>> from meshreg.samples import paper_pairs
>>> pair = paper_pairs(21, 21)[6]
>>> result = meshreg.register(pair.first, pair.second, mode="dp")
>>> result.rotation.round().astype(int).tolist()
[[0, 1, 0], [0, 0, 1], [1, 0, 0]]
"""

from .errors import InputError
from .grid import GridSurface, read_grid
from .batch import DistanceMatrix, distance_matrix
from .register import MODES, Registration, register, register_symmetric

__all__ = ["DistanceMatrix", "GridSurface", "InputError", "MODES", "Registration", "read_grid", "register", "register_symmetric", "distance_matrix"]
__version__ = "0.1.0"
