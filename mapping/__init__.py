"""Mapping core: variable-height voxels (VHV) and the maps derived from them.

Pure numerics (numpy, numba). Never imports pybullet, serial, smbus2, or sim/hw code.
"""

from mapping.errors import MappingError

__all__ = ["MappingError"]
