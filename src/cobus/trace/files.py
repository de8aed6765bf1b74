"""Opening trace files: python-can's readers, with what they do not check checked first.

python-can's BLF reader inflates each log container whole, whatever it holds: a 1.57 MB file
whose container inflates to 1.6 GB takes 1.6 GB. :func:`open_trace` first walks a BLF
file's object headers (no message is decoded) and refuses a container that announces more
than :data:`MAX_CONTAINER` bytes or inflates past what it announces (inflating it only that
far), with a :class:`TraceFileError` that says which and where. Other formats go to
python-can as they are.
"""

from __future__ import annotations

import zlib
from pathlib import Path
from typing import Any

from cobus.errors import CobusError

__all__ = ["MAX_CONTAINER", "TraceFileError", "check_blf", "open_trace"]

#: The most bytes one BLF log container may hold uncompressed. Vector's tools and python-can
#: write 128 KiB; a trace of real traffic never comes near.
MAX_CONTAINER = 16 * 1024 * 1024


class TraceFileError(CobusError, ValueError):
    """A trace file that cannot be read safely (it says which part, where and why)."""


def open_trace(path: str | Path, **options: Any) -> Any:
    """python-can's reader for ``path`` (``can.LogReader``), a BLF file checked first.
    Raises :class:`TraceFileError` for a BLF file cobus will not inflate; python-can's own
    errors (a format it does not know, a damaged file) come through as they are."""
    import can

    suffixes = [s.lower() for s in Path(path).suffixes[-2:]]
    if suffixes[-1:] == [".blf"]:
        check_blf(path)
    elif suffixes == [".blf", ".gz"]:  # (python-can reads it through gzip)
        import gzip

        with gzip.open(path, "rb") as inner:
            check_blf(path, file=inner)
    return can.LogReader(str(path), **options)


def check_blf(path: str | Path, max_container: int = MAX_CONTAINER, *, file: Any = None) -> None:
    """Walk the objects of BLF file ``path`` (read from ``file`` when given: a binary file
    object, e.g. the inside of a .blf.gz) and refuse a log container that announces more
    than ``max_container`` bytes uncompressed, or inflates to more than it announces. What
    is not a well-formed BLF file is left to python-can's reader to report."""
    if file is None:
        with open(path, "rb") as f:
            _walk(path, f, max_container)
    else:
        _walk(path, file, max_container)


def _walk(path: str | Path, f: Any, max_container: int) -> None:
    from can.io import blf

    header_size = blf.OBJ_HEADER_BASE_STRUCT.size
    container_size = blf.LOG_CONTAINER_STRUCT.size
    head = f.read(blf.FILE_HEADER_STRUCT.size)
    if len(head) < blf.FILE_HEADER_STRUCT.size:
        return
    header = blf.FILE_HEADER_STRUCT.unpack(head)
    if header[0] != b"LOGG":
        return
    offset = header[1]
    f.seek(offset)
    while True:
        data = f.read(header_size)
        if len(data) < header_size:
            return
        signature, _, _, obj_size, obj_type = blf.OBJ_HEADER_BASE_STRUCT.unpack(data)
        if signature != b"LOBJ" or obj_size < header_size:
            return
        body_size = obj_size - header_size
        if obj_type == blf.LOG_CONTAINER:
            if body_size > max_container + _SLACK:  # (deflate never grows data by more)
                raise TraceFileError(
                    f"{Path(path).name}: the log container at byte {offset:,} holds "
                    f"{body_size:,} bytes, more than the {max_container:,} cobus reads in one "
                    "(real traces hold 128 KiB a container): a damaged or hostile file; not read"
                )
            body = f.read(body_size)
            if len(body) >= container_size:
                method, announced = blf.LOG_CONTAINER_STRUCT.unpack_from(body)
                _check_container(path, offset, method, announced, body, max_container)
        else:
            f.seek(body_size, 1)  # (what python-can reads and drops)
        f.seek(obj_size % 4, 1)  # (the padding python-can's reader skips)
        offset = f.tell()


#: What a container's compressed bytes may exceed the most it may hold by.
_SLACK = 64 * 1024


def _check_container(
    path: str | Path, offset: int, method: int, announced: int, body: bytes, cap: int
) -> None:
    from can.io import blf

    where = f"{Path(path).name}: the log container at byte {offset:,}"
    if method != blf.ZLIB_DEFLATE:
        return  # (stored: its bytes are in the file already; python-can ignores the size)
    if announced > cap:
        raise TraceFileError(
            f"{where} announces {announced:,} bytes uncompressed, more than the "
            f"{cap:,} cobus inflates (real traces hold 128 KiB a container): a damaged or "
            "hostile file; not read"
        )
    inflater = zlib.decompressobj()
    try:
        out = inflater.decompress(body[blf.LOG_CONTAINER_STRUCT.size :], announced + 1)
    except zlib.error:
        return  # (python-can's reader says so)
    if len(out) > announced:
        raise TraceFileError(
            f"{where} inflates to more than the {announced:,} bytes it announces (a zip "
            "bomb?): a damaged or hostile file; not read"
        )
