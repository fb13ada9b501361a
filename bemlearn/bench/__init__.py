"""bemlearn.bench."""
