"""Loading EDS files: time (best of N) and peak memory, cobus next to python-canopen.

Two files: the largest of the shared corpus (Sevcon Gen4, 480 KB, 22k lines) and a generated
EDS with 5,000 objects (VARs, and every fifth a RECORD of four sub-objects). Peak memory is
what tracemalloc sees during one load, measured apart from the timing runs.
"""

from __future__ import annotations

import logging
import os
import tempfile
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import canopen

from benchmarks.common import best_of, header, row
from cobus.od import load

HERE = Path(__file__).resolve().parent
SHARED = Path(os.environ.get("COBUS_SHARED", HERE.parent.parent / "shared"))
SEVCON = SHARED / "eds" / "sevcon_gen4.eds"
REPEAT = 5


def generated_eds(count: int = 5000) -> str:
    """An EDS with ``count`` objects from 0x2000 on: VARs, and every fifth a 4-sub RECORD."""
    out = [
        "[FileInfo]\nFileName=generated.eds\nFileVersion=1\nFileRevision=0\nEDSVersion=4.0\n",
        "[DeviceInfo]\nVendorName=cobus\nVendorNumber=0x1\nProductName=Generated\n"
        "BaudRate_500=1\nNrOfRXPDO=0\nNrOfTXPDO=0\n",
        "[MandatoryObjects]\nSupportedObjects=0\n",
        "[OptionalObjects]\nSupportedObjects=0\n",
        f"[ManufacturerObjects]\nSupportedObjects={count}\n",
    ]
    out.extend(f"{i + 1}=0x{0x2000 + i:04X}\n" for i in range(count))
    out.append("\n")
    for i in range(count):
        index = 0x2000 + i
        if i % 5 == 4:
            out.append(
                f"[{index:04X}]\nParameterName=Record {i}\nObjectType=0x9\nSubNumber=4\n\n"
                f"[{index:04X}sub0]\nParameterName=Highest sub-index supported\n"
                "ObjectType=0x7\nDataType=0x0005\nAccessType=const\nDefaultValue=3\n"
                "PDOMapping=0\n\n"
            )
            for sub in (1, 2, 3):
                out.append(
                    f"[{index:04X}sub{sub}]\nParameterName=Field {sub}\nObjectType=0x7\n"
                    "DataType=0x0007\nAccessType=rw\nDefaultValue=0x00000000\nPDOMapping=1\n"
                    "LowLimit=0x00000000\nHighLimit=0xFFFFFFFF\n\n"
                )
        else:
            out.append(
                f"[{index:04X}]\nParameterName=Parameter {i}\nObjectType=0x7\nDataType=0x0006\n"
                f"AccessType=rw\nDefaultValue={i % 1000}\nPDOMapping=0\nLowLimit=0\n"
                "HighLimit=1000\n\n"
            )
    return "".join(out)


def _peak(fn: Callable[[], object]) -> float:
    """Peak traced allocation of one call, in KiB."""
    tracemalloc.start()
    try:
        fn()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak / 1024


def measure(path: Path) -> dict[str, float]:
    """Seconds (best of REPEAT) and peak KiB of loading ``path`` with both libraries."""
    path_text = str(path)

    def ours() -> object:
        return load(path)

    def theirs() -> object:
        return canopen.import_od(path_text)

    logging.disable(logging.WARNING)  # python-canopen logs about the files' quirks
    try:
        ours()
        theirs()  # warm up imports and caches
        return {
            "cobus_s": best_of(ours, REPEAT),
            "canopen_s": best_of(theirs, REPEAT),
            "cobus_kib": _peak(ours),
            "canopen_kib": _peak(theirs),
        }
    finally:
        logging.disable(logging.NOTSET)


def _report(title: str, figures: dict[str, float]) -> None:
    print(header(title))
    print(row("load time", figures["cobus_s"] * 1e6, figures["canopen_s"] * 1e6, "µs", False))
    print(row("peak memory", figures["cobus_kib"], figures["canopen_kib"], "KiB", False))


def main() -> None:
    files: list[tuple[str, Path]] = []
    if SEVCON.is_file():
        size = SEVCON.stat().st_size // 1024
        files.append((f"EDS load: {SEVCON.name} ({size} KB, largest of the corpus)", SEVCON))
    else:
        print(f"(skipped the Sevcon file: {SEVCON} is missing; set COBUS_SHARED)")
    with tempfile.TemporaryDirectory() as tmp:
        generated = Path(tmp) / "generated_5000.eds"
        generated.write_text(generated_eds(), encoding="utf-8")
        size = generated.stat().st_size // 1024
        files.append((f"EDS load: generated, 5,000 objects ({size} KB)", generated))
        for title, path in files:
            _report(title, measure(path))


if __name__ == "__main__":  # python -m benchmarks.bench_od, or benchmarks/run.py od
    main()
