"""Label volumes -> per-class surface meshes in millimetres -> GLB / STL / PLY."""
