"""``zcomp preview-light``: the light zcomp will use, rendered on three balls (``run``)."""
