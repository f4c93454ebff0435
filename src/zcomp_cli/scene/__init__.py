"""The scene zcomp composites into: its geometry and its light, apart from any renderer
(DESIGN.md section 5; Mitsuba's lesson: the scene is separate from the integrator).

* ``lightparams``: the light as a tree of parameters, free or frozen (the manifest's
  ``light:``, the fit's output); ``lightmodel``: a light as the renderers draw it (suns,
  lamps, a sky, in the photograph's shading units);
* ``depthmesh``, ``raycast``: the photograph's depth as a triangle mesh and Embree's rays
  through it; ``march``: screen-space rays through the depth map; ``skyvis``: the sky
  seen from a point; ``objectshadow``: the inserted object's shadow map per light;
  ``shadowreach``: where a given light's shadow of the object falls;
* ``planes``: walls beyond the frame; ``frame``: world up (the support plane, or the
  camera's pitch and roll);
* ``sh``, ``sampling``: spherical harmonics and direction sets; ``probe``: an HDR probe
  split into its sources and its sky;
* ``config``: their configs (``zcomp_cli.knobs``).

Imports nothing above it (no light fit, no renderer, no pipeline).
"""
