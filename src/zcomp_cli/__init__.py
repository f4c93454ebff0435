"""zcomp: composite 3D objects into photographs with realistic shading and shadows."""

__version__ = "0.1.0"
