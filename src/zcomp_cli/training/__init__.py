"""ZeroComp ControlNet training (`zcomp train`)."""
