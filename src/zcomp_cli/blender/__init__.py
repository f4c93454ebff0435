"""Everything that drives Blender. bpy itself is only ever imported by the scripts in
``scripts/``, which run in a subprocess (see ``runner``)."""
