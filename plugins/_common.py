"""What both adapters do with plain arrays: register two meshes and carry the results back to input vertices."""

from __future__ import annotations

import importlib

import numpy as np

from meshreg.mesh.correspond import MeshRegistration, register_meshes
from meshreg.mesh.export import colored_outputs
from meshreg.options import Options


def require(module: str, extra: str):
    """Import ``module`` or raise an ImportError that names the extra to install."""
    try:
        return importlib.import_module(module)
    except ImportError as err:
        raise ImportError(f"meshreg.plugins needs {module}: pip install 'meshreg[{extra}]' ({err})") from None


def register_arrays(
    first, second, options: Options | None = None, names=("first mesh", "second mesh")
) -> tuple[MeshRegistration, np.ndarray, np.ndarray, tuple]:
    """Register (vertices, faces) pairs; returns the mesh registration, colours (n1, 3) and (n2, 3) in [0, 1] on
    the input vertices (grey where cleanup dropped a vertex) and the registered mesh (vertices, faces, colours)."""
    mr = register_meshes(first, second, options, names=names)
    return mr, *colored_outputs(mr, len(first[0]), len(second[0]))
