"""Simulation: the compiled closed-loop simulator, its C cache, the papers' scenarios and their metrics."""
