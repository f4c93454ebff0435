"""Benchmarks with physically rendered ground truth (``zcomp make-benchmark``) and the
scene renders behind the shipped example.

Modules: ``scenes`` (scene description, random sampler, camera-frame geometry),
``objects`` (procedural GLB objects), ``render`` (the Blender subprocess and its passes),
``generate`` (planning, placement, rendering and writing a benchmark). Heavy imports
(bpy, OpenImageIO) happen only when rendering.
"""
