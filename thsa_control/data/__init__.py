"""Measured data: the rig-run format (FORMAT.md) reader and writer, run summary, export, units."""
