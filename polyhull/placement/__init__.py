"""Sensor placement quality and optimisation (paper section 4, SPEC section 5)."""
