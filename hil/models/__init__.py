"""Built-in network models from the papers (SDEA under VSIC, MCET trilateral, 2-DOF bilateral, ...)."""
