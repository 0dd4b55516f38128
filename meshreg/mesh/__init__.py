"""Mesh front end: disk-topology triangle meshes -> unit-square parametrization -> grids -> coloured meshes.

Only this subpackage (and the adapters) import mesh libraries (trimesh); the core stays on numpy arrays.
"""

from .harmonic import parametrize
from .resample import resample_grid
from .topology import DiskMesh, load_mesh, prepare_disk

__all__ = ["DiskMesh", "load_mesh", "parametrize", "prepare_disk", "resample_grid"]
