"""Output paths checked before any work: one clear error, nothing written.

Both checks try to create (and remove) a file where the output will go, so permissions, a
read-only file system and root's exemptions all answer truthfully.
"""

from __future__ import annotations

import os
from pathlib import Path

from tumblebot.errors import TumblebotError


def _writable_folder(probe: Path) -> bool:
    """Whether a file can be created in the existing folder ``probe`` (tried, then removed:
    permissions, a read-only file system and root's exemptions all answer truthfully)."""
    import tempfile

    try:
        fd, name = tempfile.mkstemp(prefix=".tumblebot-probe-", dir=probe)
    except OSError:
        return False
    os.close(fd)
    os.unlink(name)
    return True


def _first_existing(path: Path) -> Path:
    probe = path
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    return probe


def check_writable(path: Path, flag: str) -> None:
    """Refuse, before any work, an output file that cannot be written."""
    parent = path.parent if str(path.parent) else Path(".")
    if path.is_dir():
        raise TumblebotError(f"{flag} {path} is a folder, not a file")
    probe = _first_existing(parent)  # the first existing ancestor must be a writable folder
    if not probe.is_dir() or not _writable_folder(probe):
        raise TumblebotError(f"{flag} {path}: cannot write in {probe}")
    if path.exists() and not os.access(path, os.W_OK):
        raise TumblebotError(f"{flag} {path} is not writable")


def check_writable_folder(path: Path, flag: str) -> None:
    """Refuse, before any work, an output folder that cannot be created or written in."""
    if path.exists() and not path.is_dir():
        raise TumblebotError(f"{flag} {path} is a file, not a folder")
    probe = _first_existing(path)
    if not probe.is_dir():
        raise TumblebotError(f"{flag} {path}: {probe} is a file, not a folder")
    if not _writable_folder(probe):
        raise TumblebotError(f"{flag} {path}: cannot write in {probe}")
