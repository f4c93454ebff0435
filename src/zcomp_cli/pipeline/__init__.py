"""The compositing pipeline: manifest -> jobs -> composites (DESIGN.md section 2).

* ``manifest``: load and validate ``jobs.yaml`` (every problem reported at once).
* ``scene``: load a scene's photograph and maps once per batch.
* ``placement``: turn ``placement: {pixel, yaw_deg, height}`` into a camera-frame pose.
* ``job``: run one job (numbered steps), returning a ``JobOutput``.
* ``batch``: run every job with resume/overwrite, progress and a summary.
"""
