"""Writing files safely: whole or not at all, and never through a symbolic link.

:func:`replace_file` writes a new file beside the target under a fresh name (created
exclusively, so no link planted there is followed) and renames it over the target: a reader
sees the old file or the new one, and a symbolic link at the target is replaced by the file,
never written through. :func:`refusal` says why a command must not write an output (it exists
and ``--force`` was not given, it is a folder).
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from pathlib import Path

__all__ = ["refusal", "replace_file"]


def _mode_for(target: Path) -> int:
    """The mode the file gets: that of the regular file it replaces, else what open() would
    give a new one (0666 less the umask, read without changing it: /proc on Linux)."""
    with contextlib.suppress(OSError):
        now = target.lstat()
        if stat.S_ISREG(now.st_mode):
            return stat.S_IMODE(now.st_mode)
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            mask = next(int(line.split()[1], 8) for line in f if line.startswith("Umask:"))
    except (OSError, StopIteration, ValueError, IndexError):
        mask = 0o022
    return 0o666 & ~mask


def replace_file(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` whole or not at all (see the module)."""
    target = Path(path)
    mode = _mode_for(target)
    fd, partial = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".partial", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(partial, mode)  # (not mkstemp's 0600)
        os.replace(partial, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(partial)
        raise


def refusal(path: str | os.PathLike[str], force: bool) -> str | None:
    """Why a command must not write ``path`` (None: it may): it exists (a file, or a
    symbolic link, which is replaced, never followed) and ``force`` is false, or it is a
    folder."""
    target = Path(path)
    if target.is_symlink():
        if force:
            return None
        return (
            f"{target} is a symbolic link: pass --force to replace the link by the file "
            "(what it points to is never written)"
        )
    if target.is_dir():
        return f"{target} is a folder: name a file"
    if target.exists() and not target.is_file():
        return f"{target} is no regular file (a device, a pipe): name a file"
    if target.exists() and not force:
        return f"{target} exists: pass --force to overwrite it"
    return None
