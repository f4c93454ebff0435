"""A scene's light fitted to its photograph: the light stage (DESIGN.md sections 5 and 8).

One entry point: ``stage.SceneLight`` takes a scene's maps and its light tree
(``scene.lightparams.LightParams``) and returns the fitted light (``stage.FittedLight``:
the model, the filled tree, the posterior, the evidence), kept per scene. Inside:

* ``prepare``: the scene as the fit reads it (fit pixels, depth mesh, sky, bounce);
* ``evidence``, ``shadowcast``: the cast shadows a photograph shows, and a candidate
  light's shadow on them; ``search``: the posterior over directions, a light's size,
  the sun/sky split; ``posterior``: that posterior;
* ``atoms``, ``solver``: the columns a light adds to the shading, and the robust NNLS;
* ``fit``: the tree traversed, solved and filled; ``written``: the filled tree as the
  manifest's ``light:`` (``OUT/lights/<scene>.yaml``);
* ``evidence_maps``: the evidence as debug maps; ``config``: the stage's configs.

Imports ``scene`` below it, nothing above (no renderer, no pipeline).
"""
