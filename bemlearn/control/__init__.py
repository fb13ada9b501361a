"""bemlearn.control."""
