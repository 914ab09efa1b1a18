"""Stage 3a: the test image tabulated, and a model placed on it and scored (Eqs. 2-3)."""
