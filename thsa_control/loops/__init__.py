"""Loops: the sampled-data cascade (controllers), designs as data, the plant's linear adapter,
loop analysis and its math, active/standby switching."""
