"""Write result folders safely: build in a hidden sibling, then swap it in.

Rules (issue #7, item 1):

* A command replaces only a folder that it wrote itself, recognised by the
  marker file :data:`MARKER` that every output folder carries.  An empty
  folder or a missing one is fine too.  Any other folder, a file, a symbolic
  link, the current directory or one of its ancestors is refused with an
  :class:`~thsa_control.errors.OutputError`.  ``force=True`` may replace a
  foreign folder, but never one that holds an input of the command nor the
  current directory.
* A failure (exception, SIGTERM, SIGINT) while building leaves the previous
  folder untouched and removes the hidden build folder.  The swap itself runs
  with SIGTERM/SIGINT blocked, so a signal leaves either the old or the new
  complete folder.  After a crash (SIGKILL, power loss) the hidden folders
  ``.NAME.thsa-tmp-PID`` / ``.NAME.thsa-old-PID`` of dead processes (and
  the ``.NAME.old.PID`` of earlier versions) are removed by the next run
  that writes ``NAME``.
* Folders and files get the permissions of the user's umask (no 0700).

This module imports the standard library only.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import threading
from collections.abc import Callable, Iterable
from contextlib import contextmanager
from pathlib import Path

from ..errors import OutputError

__all__ = ["MARKER", "atomic_folder", "check_output_folder", "write_json"]

#: Marker file written into every output folder; its presence allows replacing the folder.
MARKER = ".thsa-output"
_SIGNALS = tuple(s for s in (getattr(signal, "SIGTERM", None), getattr(signal, "SIGINT", None),
                             getattr(signal, "SIGHUP", None)) if s is not None)


def _inside(path: Path, folder: Path) -> bool:
    try:
        path.relative_to(folder)
        return True
    except ValueError:
        return False


def check_output_folder(out_dir: str | os.PathLike, *, force: bool = False,
                        inputs: Iterable[str | os.PathLike] = ()) -> Path:
    """Check that ``out_dir`` may be (re)written; return its absolute path.

    Parameters
    ----------
    out_dir : path-like
        Target folder.
    force : bool
        Allow replacing a non-empty folder that this workbench did not write.
    inputs : iterable of path-like
        Files the command reads; a target holding one of them is always refused.

    Raises
    ------
    OutputError
        Naming the folder and the reason, in one line.
    """
    out = Path(os.path.abspath(os.fspath(out_dir)))
    shown = os.fspath(out_dir)
    if out.is_symlink():
        raise OutputError(shown, "is a symbolic link; give a real folder")
    if out.exists() and not out.is_dir():
        raise OutputError(shown, "is an existing file, not a folder; give a folder name")
    real = Path(os.path.realpath(out))
    cwd = Path(os.path.realpath(os.getcwd()))
    if _inside(cwd, real):
        raise OutputError(shown, "is the current directory or one of its parents; give a new sub-folder")
    for item in inputs:
        if item is None:
            continue
        p = Path(os.path.realpath(os.fspath(item)))
        if _inside(p, real):
            raise OutputError(shown, f"holds the input file {os.fspath(item)}; "
                                     "give another output folder (inputs are never replaced)")
    if out.is_dir():
        try:
            entries = os.listdir(out)
        except OSError as exc:
            raise OutputError(shown, f"cannot be listed: {exc.strerror}") from None
        if entries and MARKER not in entries and not force:
            raise OutputError(shown, f"is a non-empty folder not written by thsa (no {MARKER} marker); "
                                     "give a new or empty folder, or --force to replace it")
    parent = out.parent
    if parent.exists() and not parent.is_dir():
        raise OutputError(shown, f"parent {parent} is not a folder")
    return out


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


def _stale_pattern(name: str) -> re.Pattern:
    # ours, and the ``.NAME.old.PID`` of thsa-control 0.1.0 before the marker existed
    return re.compile(r"^\." + re.escape(name) + r"\.(thsa-tmp-|thsa-old-|old\.)(\d+)$")


def _remove_stale(parent: Path, name: str) -> None:
    """Remove hidden build/old folders of ``name`` left by dead processes."""
    pattern = _stale_pattern(name)
    try:
        entries = os.listdir(parent)
    except OSError:
        return
    for entry in entries:
        m = pattern.match(entry)
        if m and not _pid_alive(int(m.group(2))):
            path = parent / entry
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path, ignore_errors=True)


class _SignalGuard:
    """Turn SIGTERM/SIGINT/SIGHUP into ``SystemExit(128 + signum)`` while active (main thread only)."""

    def __init__(self):
        self.previous: dict[int, object] = {}

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig in _SIGNALS:
                try:
                    self.previous[sig] = signal.signal(sig, self._handler)
                except (ValueError, OSError):
                    pass
        return self

    @staticmethod
    def _handler(signum, frame):
        raise SystemExit(128 + signum)

    def __exit__(self, *exc):
        for sig, old in self.previous.items():
            signal.signal(sig, old)
        return False


@contextmanager
def _signals_blocked():
    can = hasattr(signal, "pthread_sigmask") and threading.current_thread() is threading.main_thread()
    old = signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS) if can else None
    try:
        yield
    finally:
        if can:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _write_marker(folder: Path, command: str) -> None:
    from .. import __version__

    text = json.dumps({"written_by": "thsa-control", "version": __version__, "command": command}) + "\n"
    (folder / MARKER).write_text(text, encoding="utf-8")


@contextmanager
def atomic_folder(out_dir: str | os.PathLike, *, force: bool = False,
                  inputs: Iterable[str | os.PathLike] = (), command: str = "thsa"):
    """Yield a hidden build folder that replaces ``out_dir`` when the block succeeds.

    Parameters
    ----------
    out_dir : path-like
        Target folder (see the module docstring for what may be replaced).
    force : bool
        Replace a non-empty folder not written by thsa (never one holding an input).
    inputs : iterable of path-like
        Input files of the command; never inside the replaced folder.
    command : str
        Recorded in the marker file.

    Raises
    ------
    OutputError
        The target may not be written (before any work).
    """
    inputs = list(inputs)
    out = check_output_folder(out_dir, force=force, inputs=inputs)
    parent = out.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(os.fspath(out_dir), f"cannot create its parent folder: {exc.strerror}") from None
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(os.fspath(out_dir), f"parent folder {parent} is not writable")
    _remove_stale(parent, out.name)
    tmp = parent / f".{out.name}.thsa-tmp-{os.getpid()}"
    old = parent / f".{out.name}.thsa-old-{os.getpid()}"
    with _SignalGuard():
        try:
            try:
                if tmp.exists():
                    shutil.rmtree(tmp)
                os.mkdir(tmp)  # umask-respecting, unlike tempfile.mkdtemp's 0700
                _write_marker(tmp, command)
            except OSError as exc:
                raise OutputError(os.fspath(out_dir), f"cannot write into {parent}: {exc.strerror or exc}") from None
            yield tmp
            with _signals_blocked():
                # re-check: the target may have changed while we computed
                check_output_folder(out, force=force, inputs=inputs)
                try:
                    if out.exists():
                        os.replace(out, old)
                    try:
                        os.replace(tmp, out)
                    except BaseException:
                        if old.exists() and not out.exists():
                            os.replace(old, out)
                        raise
                except OSError as exc:
                    raise OutputError(os.fspath(out_dir), f"cannot be replaced: {exc.strerror or exc}") from None
                shutil.rmtree(old, ignore_errors=True)
        finally:
            if tmp.exists():
                shutil.rmtree(tmp, ignore_errors=True)


def write_json(path: Path, data, default: Callable | None = None) -> Path:
    """Write ``data`` as indented JSON."""
    path.write_text(json.dumps(data, indent=2, default=default) + "\n", encoding="utf-8")
    return path
