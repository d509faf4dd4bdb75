"""Reports: figures and result folders.  Only this package imports matplotlib."""

from .build import atomic_folder, write_json

__all__ = ["atomic_folder", "write_json"]
