"""Thin adapters to where meshreg's users work: :mod:`meshreg.plugins.open3d` (Open3D TriangleMesh in and
out) and :mod:`meshreg.plugins.meshlab` (a pymeshlab MeshSet filter). Each imports its library lazily and
names the extra to install when it is missing; the core never imports either."""
