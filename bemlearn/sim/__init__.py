"""bemlearn.sim."""
