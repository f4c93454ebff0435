"""Scripts run inside a Blender (bpy) subprocess. Nothing here is imported by zcomp itself."""
