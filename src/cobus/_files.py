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
import tempfile
from pathlib import Path

__all__ = ["refusal", "replace_file"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def replace_file(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` whole or not at all (see the module)."""
    target = Path(path)
    fd, partial = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".partial", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(partial, 0o666 & ~_umask())  # (mkstemp's 0600: as open() would have made it)
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
    if target.exists() and not force:
        return f"{target} exists: pass --force to overwrite it"
    return None
