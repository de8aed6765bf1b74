"""Mutation fuzzing of every text input cobus reads: EDS/DCF files (the shared corpus), network
files, rig files, parameter files and network-variable files.

Each input is a real file with a few mutations (bytes flipped, lines dropped or doubled,
numbers made huge, control characters, deep nesting, a cut). The loaders may refuse it only
with cobus's typed errors (:class:`~cobus.errors.CobusError`: file, line and a reason);
anything else - a bare ValueError, a RecursionError, a MemoryError - is a defect.

The suite runs a few hundred inputs (tests/test_fuzz_inputs.py); ``make fuzz`` runs many more
in a separate process under a memory and time cap and prints the counts::

    python -m tests.fuzz_inputs --eds 20000 --yaml 5000
"""

from __future__ import annotations

import argparse
import random
import re
import shutil
import sys
import tempfile
import time
import traceback
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
EDS_DIR = ROOT.parent / "shared" / "eds"
EXAMPLES = ROOT / "examples"

_NUMBER = re.compile(rb"(0x[0-9A-Fa-f]+|\d+)")
_HUGE = [b"9" * 5000, b"0x" + b"F" * 40, b"-1", b"99999999999999999999", b"1e308", b"nan"]


def mutate(data: bytes, rng: random.Random, rounds: int = 3) -> bytes:
    """``data`` with 1..``rounds`` random mutations."""
    for _ in range(rng.randint(1, rounds)):
        data = rng.choice(_MUTATORS)(data, rng)
    return data


def _flip(data: bytes, rng: random.Random) -> bytes:
    if not data:
        return data
    buf = bytearray(data)
    for _ in range(rng.randint(1, 8)):
        buf[rng.randrange(len(buf))] = rng.randrange(256)
    return bytes(buf)


def _lines(data: bytes) -> list[bytes]:
    return data.split(b"\n")


def _drop_line(data: bytes, rng: random.Random) -> bytes:
    lines = _lines(data)
    del lines[rng.randrange(len(lines))]
    return b"\n".join(lines)


def _double_lines(data: bytes, rng: random.Random) -> bytes:
    lines = _lines(data)
    start = rng.randrange(len(lines))
    chunk = lines[start : start + rng.randint(1, 30)]
    at = rng.randrange(len(lines) + 1)
    return b"\n".join(lines[:at] + chunk + lines[at:])


def _swap_lines(data: bytes, rng: random.Random) -> bytes:
    lines = _lines(data)
    i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
    lines[i], lines[j] = lines[j], lines[i]
    return b"\n".join(lines)


def _huge_number(data: bytes, rng: random.Random) -> bytes:
    found = list(_NUMBER.finditer(data))
    if not found:
        return data
    m = rng.choice(found)
    return data[: m.start()] + rng.choice(_HUGE) + data[m.end() :]


def _control(data: bytes, rng: random.Random) -> bytes:
    at = rng.randrange(len(data) + 1)
    return data[:at] + bytes([rng.choice([0, 1, 7, 27, 0x7F, 0xFF, 0xC3])]) + data[at:]


def _nest(data: bytes, rng: random.Random) -> bytes:
    at = rng.randrange(len(data) + 1)
    depth = rng.choice([50, 500, 5000])
    opener = rng.choice([b"[", b"{a: ", b"- "])
    return data[:at] + opener * depth + data[at:]


_KEY_VALUE = re.compile(rb"(?m)^([ \t-]*[^\s#:][^:\n]*:[ \t]+)([^\s#{\[&*|>][^\n#]*)")


def alias_bomb(data: bytes, rng: random.Random | None = None, key: bytes = b"") -> bytes:
    """A YAML "billion laughs" (a few hundred bytes that expand to 9**9 values): anchors
    at the top of a mapping file, and the value of ``key`` (the first one; a random key with a
    plain value with ``rng``) made the alias of the biggest - the value a message would name."""
    levels = [b"lol0: &l0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    for n in range(1, 10):
        refs = b", ".join([b"*l%d" % (n - 1)] * 9)
        levels.append(b"lol%d: &l%d [%s]" % (n, n, refs))
    spots = [m for m in _KEY_VALUE.finditer(data) if not key or m.group(1).strip(b" \t-:") == key]
    if spots:
        spot = rng.choice(spots) if rng is not None else spots[0]
        data = data[: spot.start(2)] + b"*l9 " + data[spot.end(2) :]
    return b"\n".join(levels) + b"\n" + data


def _repeat_line(data: bytes, rng: random.Random) -> bytes:
    """One line (a key, in an EDS) repeated thousands of times where it is (5,000 at most:
    more only measures PyYAML's pure-Python parser, about 300 kB/s)."""
    lines = _lines(data)
    at = rng.randrange(len(lines))
    return b"\n".join(lines[:at] + [lines[at]] * rng.choice([1000, 5000]) + lines[at:])


def _indent_headers(data: bytes, rng: random.Random) -> bytes:
    """Every section header (or every line) indented by a space or a tab."""
    pad = rng.choice([b" ", b"\t"])
    if rng.random() < 0.5:
        return data.replace(b"\n[", b"\n" + pad + b"[")
    return b"\n".join(pad + line for line in _lines(data))


def _cut(data: bytes, rng: random.Random) -> bytes:
    return data[: rng.randrange(len(data) + 1)]


def _splice(data: bytes, rng: random.Random) -> bytes:
    at = rng.randrange(len(data) + 1)
    other = rng.randrange(len(data) + 1)
    return data[:at] + data[other : other + rng.randint(1, 400)] + data[at:]


_MUTATORS: list[Callable[[bytes, random.Random], bytes]] = [
    _flip,
    _drop_line,
    _double_lines,
    _swap_lines,
    _huge_number,
    _huge_number,
    _control,
    _nest,
    _cut,
    _splice,
    _repeat_line,
    _indent_headers,
    alias_bomb,
]


# ---------------------------------------------------------------------------- targets


def eds_files() -> list[Path]:
    return sorted(p for p in EDS_DIR.glob("*") if p.suffix.lower() in (".eds", ".dcf"))


def try_eds(data: bytes, name: str) -> None:
    """Load an EDS/DCF text every way the tools do; only EdsError may come out."""
    from cobus.od import EdsError, loads
    from cobus.od._cli import render_markdown, render_table

    text = data.decode("latin-1")
    for kwargs in ({}, {"strict": True}, {"node_id": 5}):
        try:
            od = loads(text, path=name, **kwargs)
        except EdsError:
            continue
        od.to_eds()
        render_table(od)
        render_markdown(od)
        if od.node_id is not None or "node_id" in kwargs:
            od.to_dcf(5, 500)


def yaml_cases() -> list[tuple[str, Path]]:
    """(kind, file) of every YAML input the examples and the built-in rigs have."""
    cases = [("network", p) for p in sorted((EXAMPLES / "networks").glob("*.yml"))]
    cases += [("rig", p) for p in sorted((ROOT / "src/cobus/sim/rigs").glob("*.yaml"))]
    cases += [("parameters", p) for p in sorted((EXAMPLES / "parameters").glob("*.yml"))]
    cases += [("netvars", p) for p in sorted((EXAMPLES / "netvars").glob("*.yml"))]
    return cases


def try_yaml(kind: str, data: bytes, source: Path, folder: Path) -> None:
    """Load a YAML input of ``kind``; only cobus's typed errors may come out. ``folder`` is a
    scratch copy of the example's folder (EDS files referenced relative to it)."""
    from cobus.errors import CobusError

    path = folder / source.name
    path.write_bytes(data)
    try:
        if kind == "network":
            from cobus.master import load_network

            load_network(path)
        elif kind == "rig":
            from cobus.sim import Rig

            Rig.load(path)
        elif kind == "parameters":
            from cobus.blocks.parameters import load_parameters

            load_parameters(path)
        else:
            from cobus.blocks.netvar_lists import load_netvars

            load_netvars(path)
    except CobusError:
        pass


def try_history(data: bytes, folder: Path) -> None:
    """Open a (damaged) alarm history every way cobus does; only AlarmHistoryError may come
    out of AlarmHistory, nothing out of AlarmHandler."""
    from cobus.blocks import AlarmHandler, AlarmHistory, AlarmHistoryError

    path = folder / "history.db"
    for leftover in folder.glob("history.db*"):
        leftover.unlink()
    path.write_bytes(data)
    try:
        with AlarmHistory(path) as history:
            history.query()
            history.opened(source="f", node=None, code=1, text="t", severity="alarm", at=1.0)
    except AlarmHistoryError:
        pass
    path.write_bytes(data)
    AlarmHandler(path).close()


def history_sample(folder: Path) -> bytes:
    """A sound alarm history of 300 rows, as bytes."""
    from cobus.blocks import AlarmHistory

    path = folder / "sample.db"
    with AlarmHistory(path) as history:
        for n in range(300):
            row = history.opened(
                source="s", node=n % 127 + 1, code=n, text="x" * (n % 40), severity="alarm", at=n
            )
            history.cleared(row, n + 0.5)
    return path.read_bytes()


def try_blf(data: bytes, folder: Path) -> None:
    """Read a (mutated, maybe bombed) BLF trace the way cobus decode does: what python-can's
    reader raises on a damaged file is allowed; running away is not (make fuzz's caps)."""
    from cobus.trace.fastread import blf_blocks
    from cobus.trace.files import TraceFileError, open_trace

    path = folder / "trace.blf"
    path.write_bytes(data)
    try:
        with open_trace(path) as reader:
            for _ in reader:
                pass
    except TraceFileError:
        pass
    except Exception as exc:  # python-can's own: BLFParseError, struct.error, zlib.error
        if isinstance(exc, MemoryError):
            raise
    try:  # (cobus decode --summary's reader: the same, or python-can's own errors)
        for _ in blf_blocks(path, 1000):
            pass
    except TraceFileError:
        pass
    except Exception as exc:  # python-can's own, once the block reader handed over to it
        if isinstance(exc, MemoryError):
            raise


def blf_sample(folder: Path) -> bytes:
    import can

    path = folder / "sample.blf"
    with can.BLFWriter(str(path)) as writer:
        for n in range(3000):
            msg = can.Message(arbitration_id=0x180 + n % 16, data=n.to_bytes(4, "little"))
            msg.timestamp = n / 1000
            writer.on_message_received(msg)
    return path.read_bytes()


def blf_bomb_mutation(data: bytes, rng: random.Random) -> bytes:
    """A log container of zeros appended that inflates far past what it announces (or
    announces it honestly)."""
    import zlib

    from can.io import blf

    inflated = rng.choice([1 << 20, 64 << 20, 512 << 20])
    deflate = zlib.compressobj()
    chunk = bytes(min(inflated, 16 << 20))
    body = b"".join(deflate.compress(chunk) for _ in range(inflated // len(chunk)))
    body += deflate.flush()
    announced = rng.choice([inflated, 128 * 1024, 0xFFFFFFFF])
    body = blf.LOG_CONTAINER_STRUCT.pack(blf.ZLIB_DEFLATE, announced) + body
    size = blf.OBJ_HEADER_BASE_STRUCT.size + len(body)
    head = blf.OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", 16, 1, size, blf.LOG_CONTAINER)
    return data + head + body + bytes(size % 4)


def scratch(source: Path, into: Path) -> Path:
    """A copy of ``source``'s folder (with what its files reference) in ``into``."""
    folder = into / source.parent.name
    if not folder.exists():
        shutil.copytree(source.parent, folder)
    return folder


# ---------------------------------------------------------------------------- make fuzz


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--eds", type=int, default=20000, help="EDS/DCF inputs")
    parser.add_argument("--yaml", type=int, default=5000, help="YAML inputs")
    parser.add_argument("--sqlite", type=int, default=500, help="damaged alarm histories")
    parser.add_argument("--blf", type=int, default=200, help="mutated and bombed BLF traces")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--slow", type=float, default=2.0, help="seconds: an input is slow")
    args = parser.parse_args(argv)
    rng = random.Random(args.seed)
    failures: list[str] = []
    slow: list[str] = []
    worst = 0.0
    sources = [(p, p.read_bytes()) for p in eds_files()]
    for n in range(args.eds):
        path, data = rng.choice(sources)
        mutated = mutate(data, rng)
        t0 = time.perf_counter()
        try:
            try_eds(mutated, path.name)
        except Exception as exc:
            failures.append(_keep(f"eds-{n}", path, mutated, exc))
        took = time.perf_counter() - t0
        worst = max(worst, took)
        if took > args.slow:
            slow.append(f"eds input {n} from {path.name}: {took:.1f} s")
    with tempfile.TemporaryDirectory() as tmp:
        cases = [(kind, p, p.read_bytes()) for kind, p in yaml_cases()]
        for n in range(args.yaml):
            kind, path, data = rng.choice(cases)
            mutated = mutate(data, rng)
            folder = scratch(path, Path(tmp))
            t0 = time.perf_counter()
            try:
                try_yaml(kind, mutated, path, folder)
            except Exception as exc:
                failures.append(_keep(f"{kind}-{n}", path, mutated, exc))
            took = time.perf_counter() - t0
            worst = max(worst, took)
            if took > args.slow:
                slow.append(f"{kind} input {n} from {path.name}: {took:.1f} s")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        binaries = [
            ("sqlite", args.sqlite, history_sample(folder), try_history, [_flip, _cut]),
            ("blf", args.blf, blf_sample(folder), try_blf, [_flip, _cut, blf_bomb_mutation]),
        ]
        for kind, count, sample, target, mutators in binaries:
            for n in range(count):
                mutated = sample
                for _ in range(rng.randint(1, 2)):
                    mutated = rng.choice(mutators)(mutated, rng)
                t0 = time.perf_counter()
                try:
                    target(mutated, folder)
                except Exception as exc:
                    failures.append(_keep(f"{kind}-{n}", folder / f"x.{kind}", mutated, exc))
                took = time.perf_counter() - t0
                worst = max(worst, took)
                if took > args.slow:
                    slow.append(f"{kind} input {n}: {took:.1f} s")
    import resource

    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(
        f"{args.eds} EDS/DCF, {args.yaml} YAML, {args.sqlite} alarm history and {args.blf} "
        f"BLF inputs (seed {args.seed})"
    )
    print(f"  untyped exceptions: {len(failures)}")
    print(f"  inputs over {args.slow:g} s: {len(slow)} (slowest {worst:.2f} s)")
    print(f"  peak memory: {peak_mb:.0f} MB")
    for line in failures[:20] + slow[:20]:
        print("  " + line)
    return 1 if failures or slow else 0


def _keep(name: str, source: Path, data: bytes, exc: BaseException) -> str:
    """Write a failing input to fuzz-failures/ for a regression file under tests/data/."""
    out = ROOT / "fuzz-failures"
    out.mkdir(exist_ok=True)
    target = out / f"{name}{source.suffix}"
    target.write_bytes(data)
    where = traceback.extract_tb(exc.__traceback__)[-1]
    return f"{target}: {type(exc).__name__}: {str(exc)[:120]} at {where.filename}:{where.lineno}"


if __name__ == "__main__":
    sys.exit(main())
