"""The CiA 309-3 ASCII gateway (issue 44, first slice): the command language line by line,
values in both dialects (CANopenNode's documented transcripts replayed), and the gateway over
a real TCP socket against a simulated device - several clients, bad lines, a client that
leaves in the middle of a transfer."""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import json
import logging
import re
import struct
import subprocess
import sys
import threading
import uuid
from collections.abc import Awaitable, Callable, Iterator
from functools import partial
from pathlib import Path
from typing import Any

import pytest

from cobus.apps.gateway import HELP, MAX_LINE, GatewayCore, GatewayError, GatewayServer, parse_line
from cobus.apps.gateway.grammar import format_error, format_value, parse_number, parse_value
from cobus.device import export_eds
from cobus.master import ConfigurationFailed, Master, NodeState, SdoUnanswered, loads_network
from cobus.proto import Frame
from cobus.proto.nmt import NmtState
from cobus.runtime import AsyncNetwork
from cobus.sim import Rig
from cobus.sim.generic import CanopenSimDevice

# ------------------------------------------------------------------ the language


def test_a_line_names_its_sequence_net_node_and_command() -> None:
    r = parse_line("[7] 1 5 r 0x1018 1 u32 # the vendor\r\n")
    assert r is not None
    assert (r.seq, r.net, r.node, r.command, r.args) == (7, 1, 5, "r", ["0x1018", "1", "u32"])
    r = parse_line("[8] 4 START")
    assert r is not None and (r.net, r.node, r.command) == (None, 4, "start")
    r = parse_line("read 0x1017 0")  # (typed by hand: no sequence number)
    assert r is not None and (r.seq, r.node, r.command) == (None, None, "read")
    assert parse_line("   # a comment") is None and parse_line("\r\n") is None
    r = parse_line('[2] w 0x2000 0 vs "a # not a comment"')
    assert r is not None and r.rest == '0x2000 0 vs "a # not a comment"'
    with pytest.raises(GatewayError) as caught:
        parse_line("[x] r 0x1000 0")
    assert caught.value.code == 101


@pytest.mark.parametrize(
    ("text", "value"),
    [("10", 10), ("0x1F", 31), ("0X1f", 31), ("010", 8), ("0", 0), ("-5", -5), ("+7", 7)],
)
def test_numbers_are_decimal_hex_or_octal(text: str, value: int) -> None:
    assert parse_number(text) == value


@pytest.mark.parametrize("text", ["08", "0x", "1.5", "ten", ""])
def test_what_is_no_number_is_a_syntax_error(text: str) -> None:
    with pytest.raises(GatewayError) as caught:
        parse_number(text)
    assert caught.value.code == 101


def test_canopennodes_documented_reads_come_out_alike() -> None:
    """CANopenDemo's tutorial/SDO.md: the same bytes give the same reply lines."""
    i64 = struct.pack("<q", -1234567890123456789)
    assert format_value("i64", i64) == "-1234567890123456789"
    u64 = bytes.fromhex("EFCDAB9078563412")
    assert format_value("x64", u64) == "0x1234567890ABCDEF"
    assert format_value("u64", u64) == "1311768467294899695"
    assert format_value(None, u64) == "EF CD AB 90 78 56 34 12"
    assert format_value("r32", struct.pack("<f", 12.345)) == "12.345"
    assert format_value("vs", b"1 2") == '"1 2"'
    assert format_value("vs", b'say "hi"') == '"say ""hi"""'
    assert format_value("os", bytes.fromhex("c83dbb00000000000000")) == "yD27AAAAAAAAAA=="
    assert format_value("u16", b"\x01") == "01"  # (a size the type does not have: its bytes)


def test_lely_writes_unsigned_numbers_in_hex_and_errors_its_way() -> None:
    assert format_value("u16", (1000).to_bytes(2, "little"), "lely") == "0x03e8"
    assert format_value("i16", (-2).to_bytes(2, "little", signed=True), "lely") == "-2"
    assert format_value("t", bytes.fromhex("e80300000a00"), "lely") == "10 1000"
    assert format_error(3, 0x06020000, "Object does not exist", "lely") == (
        "[3] ERROR: 06020000 (Object does not exist)"
    )
    assert format_error(4, 101, "Syntax error") == "[4] ERROR:101 #Syntax error"
    assert format_error(5, 0x06020000, "x") == "[5] ERROR:0x06020000 #x"


def test_values_to_write_per_type() -> None:
    written = parse_value("hex", "01 2 30 456789 0A b0 0 ff")  # (CANopenDemo's SDO.md)
    assert written == bytes.fromhex("01 02 30 45 67 89 0A B0 00 FF")
    assert parse_value("vs", '"1 2"') == b"1 2" and parse_value("vs", "one two") == b"one two"
    assert parse_value("vs", '"a ""b"""') == b'a "b"'
    assert parse_value("u16", "0x3e8") == b"\xe8\x03" and parse_value("i8", "-1") == b"\xff"
    assert parse_value("b", "1") == b"\x01" and parse_value("b", "false") == b"\x00"
    assert parse_value("r32", "1.5") == struct.pack("<f", 1.5)
    assert parse_value("os", "yD27AAAAAAAAAA==") == bytes.fromhex("c83dbb00000000000000")
    assert parse_value("td", "2 500") == bytes.fromhex("f40100000200")
    for type_name, text in [("u8", "256"), ("i8", "-129"), ("b", "2"), ("vs", '"open'),
                            ("os", "not base64!"), ("r32", "x"), ("u16", "")]:  # fmt: skip
        with pytest.raises(GatewayError) as caught:
            parse_value(type_name, text)
        assert caught.value.code == 101, (type_name, text)
    with pytest.raises(GatewayError) as caught:
        parse_value("u17", "1")
    assert caught.value.code == 101 and "u32" in caught.value.text


# ------------------------------------------------------------------ over TCP

RIG = "devices:\n  - {node: 5, kind: cia401_io}\n  - {node: 6, kind: cia401_io}\n"
Client = tuple[asyncio.StreamReader, asyncio.StreamWriter]
Scenario = Callable[[AsyncNetwork, Rig, GatewayServer], Awaitable[None]]


#: The virtual channel of each network ``served`` makes (another bus on it: another node).
CHANNEL_OF: dict[int, str] = {}


def served(scenario: Scenario, dialect: str = "canopennode") -> None:
    """``scenario(net, rig, server)`` with the gateway on a free port of 127.0.0.1, on a
    real-time loop (real sockets)."""

    async def main() -> None:
        rig = Rig.loads(RIG)
        channel = f"gw-{uuid.uuid4()}"
        async with AsyncNetwork(interface="virtual", channel=channel) as net:
            CHANNEL_OF[id(net)] = channel
            await rig.start(net)
            server = GatewayServer(GatewayCore({1: net}, dialect=dialect))
            await server.start()
            try:
                await scenario(net, rig, server)
            finally:
                await server.stop()
                await rig.stop()

    asyncio.run(asyncio.wait_for(main(), 60))


async def connect(server: GatewayServer) -> Client:
    return await asyncio.open_connection("127.0.0.1", server.port)


async def ask(client: Client, line: str, replies: int = 1) -> list[str]:
    reader, writer = client
    writer.write(line.encode() + b"\n")
    await writer.drain()
    return [(await reader.readline()).decode().rstrip("\r\n") for _ in range(replies)]


def device(rig: Rig, node: int) -> Any:
    sim = rig.device(node)
    assert isinstance(sim, CanopenSimDevice)
    return sim.device


def test_reads_writes_and_nmt_through_the_socket() -> None:
    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        c = await connect(server)
        assert await ask(c, "[1] 5 r 0x1018 1 u32") == [f"[1] {0x00C0B005}"]
        assert await ask(c, "[2] 5 r 0x1018 1 x32") == ["[2] 0x00C0B005"]
        assert await ask(c, "[3] set node 5") == ["[3] OK"]
        assert await ask(c, "[4] w 0x1017 0 u16 250") == ["[4] OK"]
        assert await ask(c, "[5] r 0x1017 0 u16") == ["[5] 250"]
        assert await ask(c, "[6] r 0x1017 0") == ["[6] FA 00"]
        (abort,) = await ask(c, "[7] r 0x5FFF 0 u8")
        assert abort.startswith("[7] ERROR:0x06020000 #")
        (bad,) = await ask(c, "[8] w 0x1017 0 u16 70000")
        assert bad.startswith("[8] ERROR:101 #")
        assert await ask(c, "[9] 6 stop") == ["[9] OK"]
        await asyncio.sleep(0.05)
        assert device(rig, 6).state is NmtState.STOPPED
        assert await ask(c, "[10] 0 start") == ["[10] OK"]
        await asyncio.sleep(0.05)
        assert device(rig, 6).state is NmtState.OPERATIONAL
        assert await ask(c, "r 0x1017 0 u16") == ["250"]  # (no [seq]: none back)
        (info,) = await ask(c, "[11] info")
        assert info.startswith("[11] cobus ") and "CiA 309-3 gateway" in info
        help_lines = await ask(c, "[12] help", len(HELP.splitlines()) + 1)
        assert help_lines[-1] == "[12] OK" and "r|read" in help_lines[1]

    served(scenario)


def test_what_a_client_gets_wrong_is_answered_and_the_connection_stays() -> None:
    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        c = await connect(server)
        assert (await ask(c, "[1] r 0x1000 0 u32"))[0].startswith("[1] ERROR:105 #")
        assert (await ask(c, "[2] 5 frobnicate"))[0].startswith("[2] ERROR:100 #")
        assert (await ask(c, "[3] 5 r 0x1000 0 u33"))[0].startswith("[3] ERROR:101 #")
        assert (await ask(c, "[4] 200 r 0x1000 0"))[0].startswith("[4] ERROR:107 #")
        assert (await ask(c, "[5] 2 5 r 0x1000 0"))[0].startswith("[5] ERROR:106 #")
        assert (await ask(c, "[6] set node 0"))[0].startswith("[6] ERROR:107 #")
        assert (await ask(c, "[7] set colour 5"))[0].startswith("[7] ERROR:100 #")
        assert (await ask(c, "[8] 5 reset everything"))[0].startswith("[8] ERROR:101 #")
        (long,) = await ask(c, "[9] " + "x" * 10_000)
        assert long.startswith("ERROR:101 #a line longer than")
        assert await ask(c, "[10] 5 r 0x1017 0 u16") == ["[10] 0"]
        assert await ask(c, "[11] set sdo_timeout 100") == ["[11] OK"]
        (silent,) = await ask(c, "[12] 99 r 0x1000 0 u32")
        assert silent.startswith("[12] ERROR:0x05040000 #")

    served(scenario)


def test_several_clients_each_with_its_defaults_and_one_that_leaves_mid_transfer() -> None:
    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        clients = [await connect(server) for _ in range(20)]
        for i, c in enumerate(clients):
            assert await ask(c, f"[{i}] set node {5 + i % 2}") == [f"[{i}] OK"]
        replies = await asyncio.gather(
            *(ask(c, f"[{i}] r 0x1018 1 u32") for i, c in enumerate(clients))
        )
        assert replies == [[f"[{i}] {0x00C0B005}"] for i in range(20)]
        assert server.clients == 20
        # one client asks a node that never answers (1.5 s) and leaves: the others go on at
        # once, its transfer ends as it would (no abort it did not ask for), then it is gone
        leaving = clients[0]
        await ask(leaving, "[1] set sdo_timeout 1500")
        leaving[1].write(b"[2] 99 r 0x1000 0\n")
        await leaving[1].drain()
        await asyncio.sleep(0.05)
        leaving[1].close()
        started = asyncio.get_running_loop().time()
        assert await ask(clients[1], "[3] r 0x1017 0 u16") == ["[3] 0"]
        assert asyncio.get_running_loop().time() - started < 1.0
        for _reader, writer in clients[1:]:
            writer.close()
        for _ in range(200):
            if server.clients == 0:
                break
            await asyncio.sleep(0.02)
        assert server.clients == 0

    served(scenario)


def test_the_lely_dialect_over_the_socket() -> None:
    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        c = await connect(server)
        assert await ask(c, "[1] 5 r 0x1018 1 u32") == ["[1] 0x00c0b005"]
        (abort,) = await ask(c, "[2] 5 r 0x5FFF 0 u8")
        assert abort.startswith("[2] ERROR: 06020000 (")
        # info version as Lely writes it: identity, class 3, CiA 309-1 2.0, implementation
        (version,) = await ask(c, "[3] info version")
        assert re.fullmatch(r"\[3\] 0 0 [0-9]+\.[0-9]+ 0 3 2\.0 [0-9]+\.[0-9]+", version)

    served(scenario, "lely")


def test_beyond_this_host_only_with_a_token() -> None:
    core = GatewayCore({1: AsyncNetwork()})
    for host in ("0.0.0.0", "192.168.1.5", "::"):
        with pytest.raises(ValueError, match=r"not only this host\) give the core a token"):
            GatewayServer(core, host)
    GatewayServer(core, "localhost")
    GatewayServer(core, "::1")
    GatewayServer(GatewayCore({1: AsyncNetwork()}, token="a-long-token"), "::")


def test_a_master_beside_the_gateway_never_sees_its_transfers_aborted(tmp_path: Path) -> None:
    """The gateway and the master share the network's one SDO transport per node: while
    clients read and write a node, the master boots it again (1000h, 1018h, its start-up
    list, heartbeat) and nothing of either side is aborted."""

    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        sim = rig.device(5)
        assert isinstance(sim, CanopenSimDevice)
        (tmp_path / "io.eds").write_text(export_eds(sim.od))
        text = (
            "master: {node_id: 1}\nnodes:\n"
            "  a: {node_id: 5, eds: io.eds, mandatory: true, heartbeat_time: 100}\n"
            "  b: {node_id: 6, eds: io.eds, mandatory: true, heartbeat_time: 100}\n"
        )
        master = Master(net, loads_network(text, base_dir=tmp_path))
        events: list[Any] = []
        master.add_listener(events.append)
        await master.boot(timeout=10)
        clients = [await connect(server) for _ in range(4)]

        async def busy(i: int, c: Client) -> list[str]:
            node = 5 + i % 2
            out = []
            for k in range(25):
                out += await ask(c, f"[{k}] {node} w 0x1017 0 u16 {100 + k}")
                out += await ask(c, f"[{k}] {node} r 0x1018 4 u32")
            return out

        replies, _ = await asyncio.gather(
            asyncio.gather(*(busy(i, c) for i, c in enumerate(clients))),
            master.restart_node(5),
        )
        assert all("ERROR" not in line for lines in replies for line in lines), replies
        assert master.nodes[5].state is NodeState.OPERATIONAL
        assert not [e for e in events if isinstance(e, ConfigurationFailed | SdoUnanswered)]
        await master.stop()
        for _reader, writer in clients:
            writer.close()

    served(scenario)


# ------------------------------------------------------------------ the client


@contextlib.contextmanager
def gateway_in_a_thread(dialect: str = "canopennode") -> Iterator[int]:
    """A gateway with the rig's devices, on its own loop in a thread: its port."""
    loop = asyncio.new_event_loop()
    ready: concurrent.futures.Future[int] = concurrent.futures.Future()
    stop = asyncio.Event()

    async def main() -> None:
        rig = Rig.loads(RIG)
        async with AsyncNetwork(interface="virtual", channel=f"gw-{uuid.uuid4()}") as net:
            await rig.start(net)
            server = GatewayServer(GatewayCore({1: net}, dialect=dialect))
            await server.start()
            ready.set_result(server.port)
            await stop.wait()
            await server.stop()
            await rig.stop()

    thread = threading.Thread(target=loop.run_until_complete, args=(main(),), daemon=True)
    thread.start()
    try:
        yield ready.result(timeout=30)
    finally:
        loop.call_soon_threadsafe(stop.set)
        thread.join(30)
        loop.close()


def gw(
    port: int, *args: str, stdin: str | None = None, options: tuple[str, ...] = ()
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "cobus", "gw", *options, f"127.0.0.1:{port}", *args],
        input=stdin,
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_cobus_gw_prints_values_as_data_and_exits_by_the_first_errors_kind(
    tmp_path: Path,
) -> None:
    with gateway_in_a_thread() as port:
        done = gw(port, "5 r 0x1018 1 u32", "5 w 0x1017 0 u16 300", "5 r 0x1017 0 u16")
        assert (done.returncode, done.stdout, done.stderr) == (0, f"{0x00C0B005}\n300\n", "")
        done = gw(port, stdin="# a file of requests\nset node 6\n\nr 0x1018 1 x32\n")
        assert (done.returncode, done.stdout) == (0, "0x00C0B005\n")
        (tmp_path / "req.txt").write_text("5 r 0x5FFF 0 u8\n5 r 0x1017 0 u16\n")
        done = gw(port, "-f", str(tmp_path / "req.txt"), "--json")
        assert done.returncode == 1  # (an abort first; the second request still answered)
        first, second = (json.loads(line) for line in done.stdout.splitlines())
        assert first["ok"] is False and first["error"] == "0x06020000"
        assert first["kind"] == "abort" and first["text"]
        assert second == {"request": "5 r 0x1017 0 u16", "ok": True, "value": "300"}
        assert gw(port, "5 r 0x1000 0 u33").returncode == 2
        done = gw(port, "r 0x1000 0 u32")
        assert done.returncode == 4 and "error 105" in done.stderr
        assert gw(port, "set sdo_timeout 50", "99 r 0x1000 0").returncode == 3
        done = gw(port, "help")
        assert done.returncode == 0 and "r|read" in done.stdout
        # options anywhere after HOST:PORT, between the requests too
        done = gw(port, "--json", "5 r 0x1017 0 u16", "--timeout", "5", "5 r 0x1018 1 x32")
        assert done.returncode == 0, done.stderr
        assert [json.loads(line)["value"] for line in done.stdout.splitlines()] == [
            "300",
            "0x00C0B005",
        ]
    with gateway_in_a_thread("lely") as port:
        done = gw(port, "5 r 0x5FFF 0 u8", "--json")
        assert done.returncode == 1 and json.loads(done.stdout)["error"] == "0x06020000"
        assert gw(port, "5 r 0x1017 0 u16").stdout == "0x0000\n"
    done = gw(port, "5 r 0x1017 0 u16")  # (the gateway is gone)
    assert done.returncode == 5 and done.stderr.startswith(f"cobus gw: 127.0.0.1:{port}: ")


def test_what_the_review_of_the_first_slice_found(caplog: pytest.LogCaptureFixture) -> None:
    """Half-closed clients get every reply, CR ends a line, [net] set checks its net, info
    takes no words, lines of exactly MAX_LINE bytes pass, and a stop with clients connected
    logs nothing."""

    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        reader, writer = await connect(server)
        writer.write(b"[1] set sdo_timeout 300\n[2] 99 r 0x1000 0\n[3] 5 r 0x1017 0 u16\n")
        await writer.drain()
        writer.write_eof()  # (printf ... | nc -N: the client half-closes and reads on)
        replies = (await reader.read()).decode().splitlines()
        # ([3] asks another node: it is answered while [2] waits for its silent node)
        assert replies[:2] == ["[1] OK", "[3] 0"] and len(replies) == 3
        assert replies[2].startswith("[2] ERROR:0x05040000 #")
        c = await connect(server)
        assert await ask(c, "[5] info\r[6] 5 r 0x1017 0 u16", 2) == [ANY_INFO, "[6] 0"]
        assert (await ask(c, "[7] 3 set node 5"))[0].startswith("[7] ERROR:106 #")
        assert await ask(c, "[8] 1 set node 5") == ["[8] OK"]
        assert (await ask(c, "[9] info please"))[0].startswith("[9] ERROR:101 #")
        exact = "[10] " + "x" * (MAX_LINE - 5)
        assert (await ask(c, exact))[0].startswith("[10] ERROR:100 #")
        (over,) = await ask(c, exact + "x")
        assert over.startswith("ERROR:101 #a line longer than")
        await connect(server)  # (left connected when the server stops)

    caplog.set_level(logging.ERROR)
    served(scenario)
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR], caplog.records


class _AnyInfo(str):
    def __eq__(self, other: object) -> bool:
        return isinstance(other, str) and other.startswith("[5] cobus ")

    __hash__ = str.__hash__


ANY_INFO = _AnyInfo("[5] cobus ...")


def test_replies_stay_one_line_and_odd_values_come_as_bytes() -> None:
    assert format_value("vs", b'A\r\nB "q" \\ \x01') == '"A\\r\\nB ""q"" \\\\ \\x01"'
    assert parse_value("vs", '"B ""q"" \\\\ \\x41"') == b'B "q" \\ A'
    # bytes as written, UTF-8 or escaped: the device says whether it takes them
    assert parse_value("vs", '"A\\r\\nB ß \\xC8"') == b"A\r\nB \xc3\x9f \xc8"
    assert format_value("vs", b"A\r\nB \xc3\x9f \xc8") == '"A\\r\\nB ß \\xC8"'
    assert parse_value("vs", "C:\\temp") == b"C:\\temp"  # (unquoted: as written)
    assert format_value("us", b"a\x00\x00\x00") == "YQAAAA=="  # (the bytes as they came)
    late = (90_000_000).to_bytes(4, "little") + b"\x00\x00"  # (ms past midnight)
    assert format_value("t", late) == "80 4A 5D 05 00 00"
    assert format_value("vs", b"") == '""'
    with pytest.raises(GatewayError):
        parse_number("1" * 50)


def test_a_time_out_in_the_lely_dialect() -> None:
    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        c = await connect(server)
        await ask(c, "[1] set sdo_timeout 100")
        assert await ask(c, "[2] 99 r 0x1000 0 u32") == ["[2] ERROR: 103 (Time-out)"]

    served(scenario, "lely")


def test_a_fuzzer_of_lines_gets_one_well_formed_answer_a_line_and_no_failure() -> None:
    """5,000 lines of random words, numbers, types, quotes and bytes through the command
    core on the simulated clock: no exception, every reply line free of line ends, and the
    last line of each answer carries the request's number or is an error line."""
    import random

    from tests.util import simulate

    rng = random.Random(309)
    words = ["r", "w", "read", "write", "set", "node", "network", "sdo_timeout", "sdo_block",
             "start", "stop", "preop", "reset", "comm", "info", "help", "u8", "i64", "vs",
             "os", "t", "td", "x32", "hex", "r32", "b", "0x1017", "0x1018", "0", "1", "4",
             "5", "-1", "0x", "010", "1e3", '"', '""', "#", "[", "]", "\\x01", "\x00"]  # fmt: skip

    def line() -> str:
        parts = [rng.choice(words) if rng.random() < 0.8 else str(rng.getrandbits(40))
                 for _ in range(rng.randint(0, 7))]  # fmt: skip
        text = " ".join(parts)
        if rng.random() < 0.1:
            text += bytes(rng.getrandbits(8) for _ in range(5)).decode("latin-1")
        return (f"[{rng.randint(0, 99)}] " if rng.random() < 0.7 else "") + text

    async def main() -> None:
        rig = Rig.loads(RIG)
        async with AsyncNetwork() as net:
            await rig.start(net)
            core = GatewayCore({1: net})
            session = core.session()
            session.sdo_timeout = 0.05
            kinds: dict[str, int] = {}
            for _ in range(5000):
                text = line().replace("\r", " ").replace("\n", " ")
                reply = await core.execute(session, text)
                error = re.search(r"ERROR:(0x[0-9A-F]{8}|[0-9]+)", reply[-1]) if reply else None
                kind = error.group(0) if error else ("OK" if reply else "none")
                kinds[kind] = kinds.get(kind, 0) + 1
                for out in reply:
                    assert "\r" not in out and "\n" not in out, (text, reply)
                request = None
                with contextlib.suppress(GatewayError):
                    request = parse_line(text)
                if request is None:
                    assert reply == [] or reply[-1].startswith("ERROR:"), (text, reply)
                elif request.seq is not None:
                    assert reply[-1].startswith(f"[{request.seq}] "), (text, reply)
            # (the fuzzer reaches the commands, not only the parser)
            assert kinds.get("OK", 0) > 20 and kinds.get("ERROR:101", 0) > 1000, kinds
            session.close()
            await rig.stop()

    simulate(main())


def test_lss_through_the_gateway() -> None:
    """The LSS requests on a device without a node-ID (the simulated clock, the core: the
    socket only carries the lines)."""
    from tests.util import simulate

    async def main() -> None:
        rig = Rig.loads("devices:\n  - {node: unconfigured, kind: cia401_io, serial: 0x1234}\n")
        async with AsyncNetwork() as net:
            await rig.start(net)
            core = GatewayCore({1: net})
            s = core.session()

            async def say(line: str) -> str:
                (reply,) = await core.execute(s, line)
                return reply

            identity = "0x00C0B005 0x00000191 0x00000001 0x00001234"
            assert await say("[1] _lss_fastscan") == f"[1] {identity}"
            assert await say("[2] lss_get_node") == "[2] 255"
            assert await say("[3] lss_inquire_addr 3") == "[3] 0x00001234"
            assert await say("[4] lss_inquire_addr") == f"[4] {identity}"
            assert (await say("[5] lss_set_node 200")).startswith("[5] ERROR:502 #")
            assert (await say("[6] lss_conf_bitrate 0 5")).startswith("[6] ERROR:503 #")
            assert await say("[7] lss_conf_bitrate 0 3") == "[7] OK"
            assert await say("[8] lss_set_node 20") == "[8] OK"
            assert await say("[9] lss_store") == "[9] OK"
            assert await say("[10] lss_switch_glob 0") == "[10] OK"
            await net.sleep(0.1)
            assert await say("[11] 20 r 0x1018 4 u32") == "[11] 4660"
            assert await say("[12] lss_switch_sel 0xC0B005 0x191 1 0x1234") == "[12] OK"
            assert await say("[13] lss_get_node") == "[13] 20"
            sim = rig.device(20)
            assert isinstance(sim, CanopenSimDevice) and sim.device.lss is not None
            sim.device.lss.store = lambda node_id, timing: False
            assert (await say("[14] lss_store")).startswith("[14] ERROR:505 #")
            assert await say("[15] lss_switch_glob 0") == "[15] OK"
            assert (await say("[16] lss_switch_sel 1 2 3 4")).startswith("[16] ERROR:103 #")
            assert (await say("[17] _lss_fastscan 100")).startswith("[17] ERROR:103 #")
            assert (await say("[18] lss_get_node")).startswith("[18] ERROR:103 #")
            assert (await say("[19] lss_frobnicate")).startswith("[19] ERROR:100 #")
            assert (await say("[20] lss_switch_glob 2")).startswith("[20] ERROR:101 #")
            assert (await say("[21] 2 lss_store")).startswith("[21] ERROR:106 #")
            s.close()
            await rig.stop()

    simulate(main())


def test_subscribed_clients_get_boot_ups_and_emergencies_as_lely_writes_them() -> None:
    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        a, b = await connect(server), await connect(server)
        assert await ask(a, "[1] subscribe") == ["[1] OK"]
        assert await ask(b, "[1] boot_up_indication enable") == ["[1] OK"]
        assert (await ask(b, "[2] subscribe everything"))[0].startswith("[2] ERROR:101 #")
        assert await ask(b, "[3] 5 reset node") == ["[3] OK"]
        assert (await a[0].readline()).decode() == "1 5 BOOT_UP\r\n"
        assert (await b[0].readline()).decode() == "1 5 BOOT_UP\r\n"
        net.send(Frame(0x86, bytes.fromhex("1023 01 0A 0B 0C 0D 0E")))
        assert (await a[0].readline()).decode() == "1 6 EMCY 2310 01 10 11 12 13 14\r\n"
        assert await ask(a, "[2] unsubscribe emcy") == ["[2] OK"]
        net.send(Frame(0x86, bytes(8)))
        assert await ask(a, "[3] 5 r 0x1017 0 u16") == ["[3] 0"]  # (no EMCY line before)
        assert await ask(b, "[4] 6 r 0x1017 0 u16") == ["[4] 0"]  # (b took boot-ups only)

    served(scenario)


def test_who_lists_the_clients_and_an_idle_client_is_closed() -> None:
    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        a, b = await connect(server), await connect(server)
        await ask(b, "[1] set node 6")
        lines = await ask(a, "[2] who", 3)
        assert lines[-1] == "[2] OK"
        mine = [line for line in lines[:2] if line.startswith("* ")]
        other = [line for line in lines[:2] if line.startswith("  ")]
        assert len(mine) == 1 and "node -, 1 requests" in mine[0]
        assert len(other) == 1 and "node 6, 1 requests" in other[0]
        assert mine[0].startswith("* 127.0.0.1:")
        server.idle_timeout = 0.3  # (from the next line each client waits for)
        await ask(a, "[3] info")
        assert (await a[0].readline()).decode() == "# idle for 0.3 s: closed\r\n"
        assert await a[0].readline() == b""  # (closed)

    served(scenario)


def test_the_client_keeps_unsolicited_lines_apart_and_a_late_reply_is_a_time_out() -> None:
    import socket

    from cobus.apps.gateway import GatewayClient

    with socket.create_server(("127.0.0.1", 0)) as listener:
        port = listener.getsockname()[1]

        def fake_gateway() -> None:
            conn, _ = listener.accept()
            with conn:
                conn.recv(100)
                conn.sendall(b"1 5 BOOT_UP\r\n1 5 EMCY 8130 11 0 0 0 0 0\r\n[1] 0\r\n")
                conn.recv(100)  # (the second request gets no reply)
                conn.recv(100)

        thread = threading.Thread(target=fake_gateway, daemon=True)
        thread.start()
        with GatewayClient("127.0.0.1", port, timeout=0.3) as client:
            reply = client.request("5 r 0x1017 0 u16")
            assert (reply.ok, reply.value, reply.lines) == (True, "0", [])
            assert client.events == ["1 5 BOOT_UP", "1 5 EMCY 8130 11 0 0 0 0 0"]
            with pytest.raises(TimeoutError):
                client.request("5 r 0x1017 0 u16")
        thread.join(5)


def test_cobus_gw_says_a_reply_that_does_not_come_in_time() -> None:
    with gateway_in_a_thread() as port:
        done = gw(
            port, "set sdo_timeout 2000", "99 r 0x1000 0", "info", options=("--timeout", "0.3")
        )
        assert done.returncode == 3
        assert "no reply within 0.3 s (--timeout); the 2 requests from there on" in done.stderr


def test_a_listening_client_is_not_idle_and_the_core_lets_the_bus_go() -> None:
    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        a = await connect(server)
        assert await ask(a, "[1] subscribe boot_up") == ["[1] OK"]
        server.idle_timeout = 0.2
        await ask(a, "[2] 5 r 0x1017 0 u16")
        await asyncio.sleep(0.6)  # (only listening)
        assert await ask(a, "[3] 5 r 0x1017 0 u16") == ["[3] 0"]
        assert (await ask(a, "[4] 5 lss_get_node"))[0].startswith("[4] ERROR:106 #no net 5")
        assert server.core._listening
        await server.stop()
        assert not server.core._listening and server.clients == 0

    served(scenario)


# ------------------------------------------------------------------ several requests at once


async def send(client: Client, *lines: str) -> None:
    client[1].write("".join(line + "\n" for line in lines).encode())
    await client[1].drain()


async def answers(client: Client, count: int) -> list[str]:
    return [(await client[0].readline()).decode().rstrip("\r\n") for _ in range(count)]


def test_numbered_requests_run_side_by_side_and_in_turn_per_node() -> None:
    """A silent node holds back no request to another node of the same client; requests to
    one node keep their order; each takes the defaults set before it, not after."""

    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        c = await connect(server)
        await send(
            c,
            "[1] set sdo_timeout 300",
            "[2] set node 99",
            "[3] r 0x1000 0",  # (node 99: silent)
            "[4] set node 5",
            "[5] w 0x1017 0 u16 100",
            "[6] r 0x1017 0 u16",  # (after [5]: same node)
            "[7] 6 r 0x1017 0 u16",
        )
        got = await answers(c, 7)
        assert got[:2] == ["[1] OK", "[2] OK"]
        assert got[-1].startswith("[3] ERROR:0x05040000 #")  # (the only one that waited)
        assert got.index("[5] OK") < got.index("[6] 100")
        assert {"[4] OK", "[7] 0"} <= set(got)

    served(scenario)


def test_unnumbered_requests_are_answered_in_order() -> None:
    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        c = await connect(server)
        await send(c, "set sdo_timeout 200", "99 r 0x1000 0", "[8] 5 r 0x1017 0 u16", "x y z")
        got = await answers(c, 4)
        assert got[0] == "OK" and got[1].startswith("ERROR:0x05040000 #")
        assert got[2] == "[8] 0" and got[3].startswith("ERROR:100 #")

    served(scenario)


def test_cancel_ends_requests_under_way_and_the_queue_is_bounded() -> None:
    from cobus.apps.gateway import MAX_PENDING

    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        aborts: list[Frame] = []
        net.subscribe(0x600 + 99, lambda frame, now: aborts.append(frame))
        c = await connect(server)
        assert await ask(c, "[1] set sdo_timeout 5000") == ["[1] OK"]
        await send(c, "[2] 99 r 0x1000 0", "[3] 99 r 0x1001 0")
        await asyncio.sleep(0.05)
        started = asyncio.get_running_loop().time()
        assert await ask(c, "[4] cancel 2", 2) == ["[4] OK", "[2] ERROR:102 #cancelled by [4]"]
        # ([2] was under way: the node is told, [3] takes its turn and is cancelled next)
        assert await ask(c, "[5] cancel", 2) == ["[5] OK", "[3] ERROR:102 #cancelled by [5]"]
        assert asyncio.get_running_loop().time() - started < 1.0
        await asyncio.sleep(0.05)
        assert [f.data[0] for f in aborts] == [0x40, 0x80, 0x40, 0x80]  # (each told)
        assert (await ask(c, "[6] cancel 42"))[0].startswith("[6] ERROR:102 #no request [42]")
        assert (await ask(c, "[7] cancel x"))[0].startswith("[7] ERROR:101 #")
        # the queue: MAX_PENDING requests wait, the next are refused, the connection stays
        await send(c, *(f"[{100 + i}] 99 r 0x1000 0" for i in range(MAX_PENDING + 3)))
        refused = await answers(c, 3)
        assert all(
            r.startswith(f"[{100 + MAX_PENDING + i}] ERROR:102 #") for i, r in enumerate(refused)
        )
        assert "under way" in refused[0]
        got = await ask(c, "[9] cancel", MAX_PENDING + 1)
        assert got[0] == "[9] OK" and len(set(got[1:])) == MAX_PENDING
        assert all(g.endswith("ERROR:102 #cancelled by [9]") for g in got[1:])
        assert await ask(c, "[10] 5 r 0x1017 0 u16") == ["[10] 0"]

    served(scenario)


def test_a_client_gone_with_requests_queued_holds_back_nobody() -> None:
    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        gone = await connect(server)
        await send(gone, "[1] set sdo_timeout 400", *(f"[{i}] 99 r 0x1000 0" for i in range(2, 12)))
        await asyncio.sleep(0.05)
        gone[1].close()
        other = await connect(server)
        await ask(other, "[1] set sdo_timeout 100")
        started = asyncio.get_running_loop().time()
        (late,) = await ask(other, "[2] 99 r 0x1000 0")
        assert late.startswith("[2] ERROR:0x05040000 #")
        assert asyncio.get_running_loop().time() - started < 0.9  # (one transfer's wait)
        for _ in range(100):  # (its queue dropped: gone within a transfer or two)
            if server.clients == 1:
                break
            await asyncio.sleep(0.05)
        assert server.clients == 1

    served(scenario)


# ------------------------------------------------------------------ tokens, Unix sockets, nets


def test_with_a_token_writes_nmt_and_lss_wait_for_it() -> None:
    async def main() -> None:
        rig = Rig.loads(RIG)
        async with AsyncNetwork(interface="virtual", channel=f"gw-{uuid.uuid4()}") as net:
            await rig.start(net)
            core = GatewayCore({1: net}, token="s3cret-token")
            server = GatewayServer(core, "127.0.0.1", 0)
            await server.start()
            try:
                c = await connect(server)
                assert await ask(c, "[1] 5 r 0x1017 0 u16") == ["[1] 0"]  # (reads: free)
                for seq, line in enumerate(
                    ["5 w 0x1017 0 u16 9", "5 stop", "0 reset node", "lss_switch_glob 1"], 2
                ):
                    (refused,) = await ask(c, f"[{seq}] {line}")
                    assert refused.startswith(f"[{seq}] ERROR:102 #") and "auth TOKEN" in refused
                assert (await ask(c, "[6] auth guess-guess"))[0].startswith("[6] ERROR:102 #")
                assert (await ask(c, "[7] auth"))[0].startswith("[7] ERROR:101 #")
                assert await ask(c, "[8] auth s3cret-token") == ["[8] OK"]
                assert await ask(c, "[9] 5 w 0x1017 0 u16 9") == ["[9] OK"]
                (who,) = (await ask(c, "[10] who", 2))[:1]
                assert "s3cret" not in who
                other = await connect(server)  # (each client gives it)
                assert (await ask(other, "[1] 5 stop"))[0].startswith("[1] ERROR:102 #")
                assert device(rig, 5).state is not NmtState.STOPPED
            finally:
                await server.stop()
                await rig.stop()
            with pytest.raises(ValueError, match="token"):
                GatewayServer(GatewayCore({1: net}), "0.0.0.0", 0)
            assert GatewayServer(core, "0.0.0.0", 0).address == "0.0.0.0:0"
            with pytest.raises(ValueError, match="8 characters"):
                GatewayCore({1: net}, token="short")
            with pytest.raises(ValueError, match=r"1\.\.127"):
                GatewayCore({0: net})
            # without a token, auth says there is none
            plain = GatewayCore({1: net})
            assert (await plain.execute(plain.session(), "[1] auth x"))[0].startswith(
                "[1] ERROR:102 #this gateway has no token"
            )

    asyncio.run(asyncio.wait_for(main(), 60))


def test_a_unix_socket_is_this_users_and_serves_several_nets(tmp_path: Path) -> None:
    import os
    import stat

    from cobus.apps.gateway import GatewayClient

    path = str(tmp_path / "gw.sock")

    async def main() -> None:
        rig1 = Rig.loads("devices:\n  - {node: 5, kind: cia401_io}\n")
        rig2 = Rig.loads("devices:\n  - {node: 7, kind: cia401_io}\n")
        async with (
            AsyncNetwork(interface="virtual", channel=f"gw-{uuid.uuid4()}") as net1,
            AsyncNetwork(interface="virtual", channel=f"gw-{uuid.uuid4()}") as net2,
        ):
            await rig1.start(net1)
            await rig2.start(net2)
            with open(path, "w"):  # (a file that is no socket is refused)
                pass
            refused = GatewayServer(GatewayCore({1: net1}), unix=path)
            with pytest.raises(OSError, match="no socket"):
                await refused.start()
            os.unlink(path)
            server = GatewayServer(GatewayCore({1: net1, 2: net2}), unix=path)
            await server.start()
            try:
                assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
                assert server.address == path
                twin = GatewayServer(GatewayCore({1: net1}), unix=path)
                with pytest.raises(OSError, match="another server listens"):
                    await twin.start()

                def as_client() -> list[str | None]:
                    with GatewayClient(unix=path, timeout=10) as client:
                        replies = [
                            client.request("5 r 0x1018 1 u32"),
                            client.request("2 7 r 0x1018 1 u32"),
                            client.request("set network 2"),
                            client.request("7 r 0x1017 0 u16"),
                            client.request("5 r 0x1017 0 u16"),  # (no node 5 on net 2)
                            client.request("3 5 r 0x1017 0 u16"),
                            client.request("info"),
                            client.request("who"),
                        ]
                    values = [r.value if r.ok else f"E{r.code}" for r in replies]
                    values[-1] = replies[-1].lines[0]
                    return values

                got = await asyncio.to_thread(as_client)
                assert got[:3] == [str(0x00C0B005), str(0x00C0B005), None]
                assert got[3] == "0" and got[4] == f"E{0x05040000}" and got[5] == "E106"
                assert got[6] is not None and got[6].endswith("nets 1, 2")
                assert got[7] is not None and re.match(
                    rf"\* {re.escape(path)}#[0-9]+ net 2 node -", got[7]
                )
            finally:
                await server.stop()
                await rig1.stop()
                await rig2.stop()
            assert not os.path.exists(path)
            # a socket left by a gateway that is gone is taken over
            import socket

            stale = socket.socket(socket.AF_UNIX)
            stale.bind(path)
            stale.close()
            again = GatewayServer(GatewayCore({1: net1}), unix=path)
            await again.start()
            await again.stop()

    asyncio.run(asyncio.wait_for(main(), 60))


def test_cobus_gateway_with_two_nets_a_unix_socket_and_a_token_beyond_this_host(
    tmp_path: Path,
) -> None:
    import os
    import signal

    path = str(tmp_path / "gw.sock")
    base = [sys.executable, "-m", "cobus", "gateway", "-i", "virtual", "-c", f"gw-{uuid.uuid4()}"]

    def started(*options: str) -> tuple[subprocess.Popen[str], str]:
        proc = subprocess.Popen(
            [*base, *options], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        assert proc.stdout is not None
        lines = ""
        while "serving" not in lines:
            line = proc.stdout.readline()
            assert line, proc.stderr.read() if proc.stderr else ""
            lines += line
        return proc, lines

    def stopped(proc: subprocess.Popen[str]) -> str:
        proc.send_signal(signal.SIGINT)
        _out, err = proc.communicate(timeout=30)
        assert proc.returncode == 0
        return err

    proc, said = started(
        "--net", f"2=virtual:gw-{uuid.uuid4()}", "--unix", path, "--node-id", "2:64"
    )
    try:
        assert said == f"cobus gateway: serving nets 1, 2 on {path}\n"
        done = subprocess.run(
            [sys.executable, "-m", "cobus", "gw", path, "info", "2 0 start"],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert done.returncode == 0 and done.stdout.strip().endswith("nets 1, 2")
        done = subprocess.run(
            [sys.executable, "-m", "cobus", "gw", path, "2 64 r 0x1008 0 vs"],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert (done.returncode, done.stdout) == (0, '"cobus CiA 309-3 gateway"\n'), done
    finally:
        err = stopped(proc)
    assert err == f"cobus gateway: stopped by Ctrl-C after serving on {path}\n"

    proc, said = started("--listen", "0.0.0.0:0")
    try:
        token = re.search(r"auth (\S+)\n", said)
        port = re.search(r"on 0\.0\.0\.0:([0-9]+)", said)
        assert token and port, said
        env = {k: v for k, v in os.environ.items() if k != "COBUS_GATEWAY_TOKEN"}
        ask_ = [sys.executable, "-m", "cobus", "gw", f"127.0.0.1:{port[1]}", "0 start"]
        done = subprocess.run(ask_, capture_output=True, text=True, timeout=60, env=env)
        assert done.returncode == 4 and "auth TOKEN" in done.stderr
        env["COBUS_GATEWAY_TOKEN"] = token[1]
        done = subprocess.run(ask_, capture_output=True, text=True, timeout=60, env=env)
        assert (done.returncode, done.stderr) == (0, "")
        env["COBUS_GATEWAY_TOKEN"] = "not-the-token"
        done = subprocess.run(ask_, capture_output=True, text=True, timeout=60, env=env)
        assert done.returncode == 4 and "refused the token" in done.stderr
    finally:
        stopped(proc)

    proc, said = started("--http", "127.0.0.1:0")  # (HTTP alone: no text port)
    try:
        import urllib.request

        http = re.search(r"on (http://127\.0\.0\.1:[0-9]+)\n", said)
        assert http, said
        with urllib.request.urlopen(f"{http[1]}/cia309-5/1.0/1/1/none/info/version") as r:
            assert json.loads(r.read())["GatewayClass"] == "3"
    finally:
        stopped(proc)

    # --json and --eds reach the server: JSON lines in and out, names from the EDS
    from cobus.device import minimal_od

    eds = tmp_path / "io.eds"
    eds.write_text(export_eds(minimal_od()))
    jpath = str(tmp_path / "json.sock")
    proc, said = started("--json", "--eds", f"5={eds}", "--unix", jpath)
    try:
        import socket

        with socket.socket(socket.AF_UNIX) as sock:
            sock.settimeout(10)
            sock.connect(jpath)
            sock.sendall(
                b'{"line": "set sdo_timeout 50"}\n'
                b'{"node": 5, "command": "r", "args": ["Producer heartbeat time"]}\n'
                b'{"node": 5, "command": "r", "args": ["No such name"]}\n'
            )
            got = b""
            while got.count(b"\n") < 3:
                chunk = sock.recv(4096)
                assert chunk, got
                got += chunk
        first, named, unknown = (json.loads(line) for line in got.splitlines())
        assert first["ok"] is True
        assert named["error"] == "0x05040000"  # (found in the EDS, asked: nobody answers)
        assert unknown["error"] == 101 and "No such name" in unknown["text"]
    finally:
        stopped(proc)

    for options, said in [
        (["--net", "1=virtual:x"], "--net numbers the other buses 2..127"),
        (["--net", "2=virtual"], "give N=INTERFACE:CHANNEL"),
        (["--net", "200=virtual:x"], "2..127"),
        (["--net", "٢=virtual:x"], "give N=INTERFACE:CHANNEL"),
        (["--net", "2=virtual:x", "--net", "2=virtual:y"], "net 2 is given twice"),
        (["--net", "2=socketcan:can1@0"], "a bit rate of 0"),
        (["--token", "short"], "8 characters"),
        (["--token", "has#hash-in-it"], "without spaces or #"),
        (["--eds", "5"], "give [NET:]NODE=FILE"),
        (["--node-id", "0"], "1..127"),
        (["--node-id", "x"], "give [NET:]NODE"),
        (["--node-id", "3:5"], "there is no net 3"),
        (["--eds", "3:5=x.eds"], "there is no net 3"),
        (["--eds", f"5={tmp_path}/none.eds"], "none.eds: cannot read the file"),
    ]:
        done = subprocess.run([*base, *options], capture_output=True, text=True, timeout=60)
        assert done.returncode == 2 and said in done.stderr, done.stderr


def test_subscribed_clients_hear_heartbeats_start_stop_and_change_state() -> None:
    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        a, quiet = await connect(server), await connect(server)
        assert await ask(a, "[1] subscribe error_control boot_up") == ["[1] OK"]

        assert await ask(a, "[2] 5 start") == ["[2] OK"]
        # the first beat: the heartbeat started, in the state the node reports
        got = await ask(a, "[3] 5 w 0x1017 0 u16 100", 2)
        assert got == ["[3] OK", "1 5 ERRORx OPER 202 (Heartbeat started)"]
        assert await ask(a, "[4] 5 preop", 2) == ["[4] OK", "1 5 ERRORx PREO"]
        await asyncio.sleep(0.35)  # (three beats: the gateway knows the period)
        started = asyncio.get_running_loop().time()
        got = await ask(a, "[5] 5 w 0x1017 0 u16 0", 2)
        assert got == ["[5] OK", "1 5 ERRORx PREO 203 (Heartbeat lost)"]
        assert asyncio.get_running_loop().time() - started < 0.5  # (2.5 periods, not more)
        got = await ask(a, "[6] 5 w 0x1017 0 u16 50", 2)
        assert got == ["[6] OK", "1 5 ERRORx PREO 202 (Heartbeat started)"]
        assert await ask(a, "[7] 5 reset node", 2) == ["[7] OK", "1 5 BOOT_UP"]
        assert await ask(quiet, "[1] 6 r 0x1017 0 u16") == ["[1] 0"]  # (nothing before)

    served(scenario)


# ------------------------------------------------------------------ documented transcripts

#: CANopenDemo's tutorial/SDO.md, request then reply (see the file's head).
CANOPENDEMO_SDO = Path(__file__).with_name("data") / "canopendemo_sdo.txt"


def _demo_device(net: AsyncNetwork) -> Any:
    """The objects of CANopenDemo's demoDevice the transcript uses, as it behaves: a string
    of 3 bytes at most, one of 1,000, an octet string of exactly 10, and a read-only average
    of the record's four numbers."""
    from cobus.device import DictionaryBuilder, add_device
    from cobus.od import DataType
    from cobus.proto.sdo import SdoAbort

    b = DictionaryBuilder(device_name="demoDevice")
    b.record(0x2120, "Demo record")
    b.variable(0x2120, "I64", DataType.INTEGER64, subindex=1, default=-1234567890123456789)
    b.variable(0x2120, "U64", DataType.UNSIGNED64, subindex=2, default=0x1234567890ABCDEF)
    b.variable(0x2120, "R32", DataType.REAL32, subindex=3, default=12.345)
    b.variable(0x2120, "R64", DataType.REAL64, subindex=4, default=456.789)
    b.variable(0x2120, "Average", DataType.REAL64, subindex=5, access="ro", default=0.0)
    b.record(0x2121, "Demo strings")
    b.variable(0x2121, "Short", DataType.VISIBLE_STRING, subindex=1, default="str")
    # (a DOMAIN: a cobus device takes visible ASCII only in a VISIBLE_STRING, CANopenNode's
    # demoDevice any bytes - here UTF-8)
    b.variable(0x2121, "Long", DataType.DOMAIN, subindex=2, default=b"x")
    octets = bytes.fromhex("C83DBB00000000000000")
    b.variable(0x2121, "Octets", DataType.OCTET_STRING, subindex=3, default=octets)
    device = add_device(net, 4, b.build())

    def capacity(size: int, exact: bool = False) -> Callable[[Any], None]:
        def check(value: Any) -> None:
            length = len(value.encode() if isinstance(value, str) else value)
            if length > size:
                raise SdoAbort(0x06070012)
            if exact and length < size:
                raise SdoAbort(0x06070013)

        return check

    device.on_write(0x2121, 1, capacity(3))
    device.on_write(0x2121, 2, capacity(1000))
    device.on_write(0x2121, 3, capacity(10, exact=True))
    device.on_read(0x2120, 5, lambda: sum(float(device.get(0x2120, s)) for s in (1, 2, 3, 4)) / 4)
    return device


def test_canopendemos_sdo_transcript_replayed_line_for_line() -> None:
    """Over the socket, one request at a time as cocomm sends them; every reply line as
    documented (an error line up to its text, which is CiA 301's wording: CANopenNode says
    "too short" where CiA 301 says "too low")."""
    text = CANOPENDEMO_SDO.read_text(encoding="utf-8")
    pairs = [line for line in text.splitlines() if line and not line.startswith("#")]
    assert len(pairs) % 2 == 0

    async def main() -> None:
        async with AsyncNetwork(interface="virtual", channel=f"gw-{uuid.uuid4()}") as net:
            _demo_device(net)
            server = GatewayServer(GatewayCore({1: net}))
            await server.start()
            try:
                c = await connect(server)
                for request, documented in zip(pairs[::2], pairs[1::2], strict=True):
                    (reply,) = await ask(c, request)
                    if "ERROR:" in documented:
                        head, _, text = documented.partition(" #")
                        assert reply.partition(" #")[0] == head, request
                        assert text.split(",")[0] in reply, request
                    else:
                        assert reply == documented, request
            finally:
                await server.stop()

    asyncio.run(asyncio.wait_for(main(), 60))


def test_what_the_review_of_pipelining_and_tokens_found() -> None:
    """A request cancelled before it ever ran is answered; a line too long and a full queue
    are answered in their turn when unnumbered; a client gone with a write queued at a node
    behind another client's transfer writes nothing."""

    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        server.idle_timeout = None  # (lines already read are taken without a pause)
        c = await connect(server)
        assert await ask(c, "[1] set sdo_timeout 3000") == ["[1] OK"]
        await send(c, "[2] 99 r 0x1000 0", "[3] cancel 2")
        assert await answers(c, 2) == ["[3] OK", "[2] ERROR:102 #cancelled by [3]"]
        assert await ask(c, "[4] set sdo_timeout 200") == ["[4] OK"]
        await send(c, "99 r 0x1000 0", "x" * (MAX_LINE + 1), "5 r 0x1017 0 u16")
        got = await answers(c, 3)
        assert got[0].startswith("ERROR:0x05040000") and got[1].startswith("ERROR:101 #")
        assert got[2] == "0"
        # a client gone with a write waiting for node 99 behind another client's read
        frames: list[str] = []
        net.subscribe(0x600 + 99, lambda frame, now: frames.append(frame.data.hex()))
        a = await connect(server)
        await send(a, "[1] set sdo_timeout 600", "[2] 99 r 0x1000 0")
        b = await connect(server)
        await send(b, "[1] set sdo_timeout 600", "[2] 99 w 0x2000 0 u8 7")
        await asyncio.sleep(0.2)
        import socket

        # (it resets the connection: a client that only closes its side is answered)
        linger = struct.pack("ii", 1, 0)
        b[1].get_extra_info("socket").setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, linger)
        b[1].transport.abort()
        assert (await answers(a, 2))[1].startswith("[2] ERROR:0x05040000")
        await asyncio.sleep(0.3)
        assert [f[:2] for f in frames] == ["40", "80"]  # (A's read and its abort only)

    served(scenario)


def test_the_unnumbered_queue_full_answer_comes_in_its_turn() -> None:
    from cobus.apps.gateway import MAX_PENDING

    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        c = await connect(server)
        assert await ask(c, "set sdo_timeout 20") == ["OK"]
        await send(c, *["99 r 0x1000 0"] * MAX_PENDING, "5 r 0x1017 0 u16")
        got = await answers(c, MAX_PENDING + 1)
        assert all(g.startswith("ERROR:0x05040000") for g in got[:MAX_PENDING])
        assert got[-1].startswith("ERROR:102 #") and "under way" in got[-1]

    served(scenario)


def test_tokens_are_one_word_guessing_costs_time_and_who_needs_it(tmp_path: Path) -> None:
    from cobus.apps.gateway import GatewayClient
    from cobus.apps.gateway.client import TokenRefused

    async def main() -> None:
        async with AsyncNetwork(interface="virtual", channel=f"gw-{uuid.uuid4()}") as net:
            for bad in ("abc#defgh", "abcd efgh", "short"):
                with pytest.raises(ValueError, match="without spaces or #"):
                    GatewayCore({1: net}, token=bad)
            core = GatewayCore({1: net}, token="the-right-token")
            tcp = GatewayServer(core, "127.0.0.1", 0)
            unix = GatewayServer(core, unix=str(tmp_path / "gw.sock"))
            await tcp.start()
            await unix.start()
            try:
                c = await connect(tcp)
                assert (await ask(c, "[1] who"))[0].startswith("[1] ERROR:102 #who: ")
                started = asyncio.get_running_loop().time()
                await send(c, *(f"[{i}] auth wrong-{i}" for i in range(2, 8)))
                got = await answers(c, 6)
                assert asyncio.get_running_loop().time() - started >= 4.5  # (one at a time)
                assert got[-1] == "[7] ERROR:102 #5 wrong tokens: connect again"
                assert (await ask(c, "[8] auth the-right-token"))[0].startswith("[8] ERROR:102")
                # a client of this user's Unix socket needs none; the client gives the token
                # only when asked, so a gateway that asks for none never sees it
                reader, writer = await asyncio.open_unix_connection(str(tmp_path / "gw.sock"))
                assert await ask((reader, writer), "[1] 0 start") == ["[1] OK"]

                def as_client(token: str) -> list[bool]:
                    with GatewayClient("127.0.0.1", tcp.port, 10, token=token) as client:
                        return [client.request("5 r 0x1017 0 u16").ok, client.request("0 start").ok]

                assert await asyncio.to_thread(as_client, "the-right-token") == [False, True]
                with pytest.raises(TokenRefused):
                    await asyncio.to_thread(as_client, "not-the-token")
                plain = GatewayServer(GatewayCore({1: net}), "127.0.0.1", 0)
                await plain.start()
                try:

                    def no_token_asked() -> bool:
                        with GatewayClient("127.0.0.1", plain.port, 10, token="unused-token") as g:
                            return g.request("0 start").ok

                    assert await asyncio.to_thread(no_token_asked)
                finally:
                    await plain.stop()
            finally:
                await tcp.stop()
                await unix.stop()

    asyncio.run(asyncio.wait_for(main(), 60))


def test_net_options_keep_channels_with_colons_and_at_signs() -> None:
    from cobus.apps._gateway_cli import _net_spec

    assert _net_spec("2=socketcand:10.0.0.1:29536") == (
        2,
        {"interface": "socketcand", "channel": "10.0.0.1:29536"},
    )
    assert _net_spec("3=remote:ws://u@host:54701")[1]["channel"] == "ws://u@host:54701"
    assert _net_spec("4=slcan:/dev/ttyACM0@500000")[1] == {
        "interface": "slcan",
        "channel": "/dev/ttyACM0",
        "bitrate": 500000,
    }


def test_objects_by_their_eds_names_and_types(tmp_path: Path) -> None:
    async def main() -> None:
        rig = Rig.loads(RIG)
        async with AsyncNetwork(interface="virtual", channel=f"gw-{uuid.uuid4()}") as net:
            await rig.start(net)
            sim = rig.device(5)
            assert isinstance(sim, CanopenSimDevice)
            core = GatewayCore({1: net}, dictionaries={(1, 5): sim.od})
            s = core.session()
            ask_ = partial(core.execute, s)
            assert await ask_('[1] 5 r "Identity object.Vendor-ID" x32') == ["[1] 0x00C0B005"]
            assert await ask_('[2] 5 r "identity object.vendor id"') == [f"[2] {0x00C0B005}"]
            assert await ask_('[3] 5 w "Producer heartbeat time" 0') == ["[3] OK"]
            assert await ask_("[4] 5 w Producer_heartbeat_time u16 0") == ["[4] OK"]
            assert await ask_("[5] 5 r 0x1017 0") == ["[5] 0"]  # (u16, as the EDS says)
            (name,) = await ask_('[6] 5 r "Manufacturer device name"')
            assert name.startswith('[6] "') and name.endswith('"')
            (wrong,) = await ask_('[7] 5 r "Producer heartbeet time"')
            assert wrong.startswith("[7] ERROR:101 #") and "Producer heartbeat time" in wrong
            (none,) = await ask_('[8] 6 r "Device name"')
            assert none.startswith("[8] ERROR:101 #") and "--eds 6=FILE" in none
            (open_quote,) = await ask_('[9] 5 r "Device name')
            assert open_quote.startswith("[9] ERROR:101 #")
            assert await ask_("[10] 6 r 0x1017 0") == ["[10] 00 00"]  # (no EDS: bytes)
            await rig.stop()

    asyncio.run(asyncio.wait_for(main(), 60))


# ------------------------------------------------------------------ PDOs (Lely's)


def test_pdo_configurations_fields_and_what_is_refused() -> None:
    from cobus.apps.gateway.pdo import pack, parse_pdo_config, unpack

    c = parse_pdo_config(["1", "0x181", "event", "3", "u8", "0x2000", "1", "i16", "b"])
    assert (c.number, c.cob_id, c.transmission, c.lengths) == (1, 0x181, 0xFF, [8, 16, 8])
    assert parse_pdo_config(["2", "0x182", "sync7", "0"]).transmission == 7
    x = parse_pdo_config(["3", "0x183", "event", "0", "0", "1", "u32"], extended=True)
    assert (x.inhibit_ms, x.event_ms, x.lengths) == (0, 0, [32])
    with pytest.raises(GatewayError) as refused:  # (a TPDO goes when written: no timers)
        parse_pdo_config(["3", "0x183", "event", "10", "500", "1", "u32"], extended=True)
    assert refused.value.code == 100
    assert parse_pdo_config(["4", "0xA0000184", "rtr", "1", "u8"]).extended
    assert pack([8, 16], [5, 0x1234]) == bytes([5, 0x34, 0x12])
    assert unpack([8, 16], bytes([5, 0x34, 0x12, 9])) == [5, 0x1234]
    assert unpack([8, 16], b"\x05") is None
    for words, code in [
        ("1 0x181 sometimes 1 u8", 101),
        ("1 0x181 sync241 1 u8", 101),
        ("1 0x181 event 1 vs", 101),
        ("0 0x181 event 1 u8", 101),
        ("1 0x800 event 1 u8", 101),
        ("1 0x181 event 2 u8", 101),
        ("1 0x181 event 1 u8 u8", 101),
        ("1 0x181 event 9 u8 u8 u8 u8 u8 u8 u8 u8 u8", 401),
    ]:
        with pytest.raises(GatewayError) as caught:
            parse_pdo_config(words.split())
        assert caught.value.code == code, words
    with pytest.raises(GatewayError):
        pack([8], [256])


def test_the_gateways_own_pdos_as_lely_has_them() -> None:
    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        sent: list[tuple[int, str]] = []
        for cob_id in (0x201, 0x202, 0x203):
            net.subscribe(
                cob_id, lambda f, now: None if f.rtr else sent.append((f.cob_id, f.data.hex()))
            )
        c = await connect(server)
        assert await ask(c, "[1] subscribe pdo") == ["[1] OK"]
        assert await ask(c, "[2] set rpdo 1 0x181 event 2 u8 u16") == ["[2] OK"]
        assert await ask(c, "[3] r p 1") == ["[3] 1 pdo 2 0x0 0x0"]  # (nothing yet)
        net.send(Frame(0x181, bytes([5, 0x34, 0x12])))
        assert (await c[0].readline()).decode() == "1 pdo 1 2 0x5 0x1234\r\n"
        assert await ask(c, "[4] 1 r p 1") == ["[4] 1 pdo 2 0x5 0x1234"]
        net.send(Frame(0x181, b"\x05"))  # (too short for its mapping: not taken)
        assert await ask(c, "[5] r p 1") == ["[5] 1 pdo 2 0x5 0x1234"]
        # synchronous: taken at the next SYNC
        assert await ask(c, "[6] set rpdo 2 0x182 sync0 1 0x2000 1 u32") == ["[6] OK"]
        net.send(Frame(0x182, (0xDEADBEEF).to_bytes(4, "little")))
        await asyncio.sleep(0.02)
        assert await ask(c, "[7] r p 2") == ["[7] 1 pdo 1 0x0"]
        net.send(Frame(0x80, b""))
        assert (await c[0].readline()).decode() == "1 pdo 2 1 0xdeadbeef\r\n"
        assert (await ask(c, "[8] set rpdo 3 0x181 event 1 u8"))[0].startswith("[8] ERROR:400 #")
        # TPDOs: at once, every 2nd SYNC, on a remote frame
        assert await ask(c, "[9] set tpdo 1 0x201 event 2 i16 u8") == ["[9] OK"]
        assert await ask(c, "[10] w p 1 2 0xffff 7") == ["[10] OK"]
        assert (await ask(c, "[11] w p 1 1 5"))[0].startswith("[11] ERROR:101 #")
        assert (await ask(c, "[12] w p 1 2 0x1ffff 1"))[0].startswith("[12] ERROR:101 #")
        assert await ask(c, "[13] set tpdo 2 0x202 sync2 1 u8") == ["[13] OK"]
        assert await ask(c, "[14] set tpdo 3 0x203 rtr 1 u8") == ["[14] OK"]
        assert await ask(c, "[15] w p 2 1 9") == ["[15] OK"]
        assert await ask(c, "[16] w p 3 1 4") == ["[16] OK"]
        await asyncio.sleep(0.02)
        assert sent == [(0x201, "ffff07")]
        for _ in range(4):
            net.send(Frame(0x80, b""))
        net.send(Frame(0x203, rtr=True, dlc=1))
        await asyncio.sleep(0.05)
        assert sent[1:] == [(0x202, "09"), (0x202, "09"), (0x203, "04")]
        assert (await ask(c, "[17] r p 9"))[0].startswith("[17] ERROR:102 #RPDO 9")
        assert (await ask(c, "[18] w p 9 1 1"))[0].startswith("[18] ERROR:102 #TPDO 9")
        assert (await ask(c, "[19] 3 r p 1"))[0].startswith("[19] ERROR:106 #")

    served(scenario)


def test_pdo_settings_and_writes_need_the_token() -> None:
    async def main() -> None:
        async with AsyncNetwork(interface="virtual", channel=f"gw-{uuid.uuid4()}") as net:
            core = GatewayCore({1: net}, token="pdo-token-1")
            s = core.session()
            for line in ("[1] set rpdo 1 0x181 event 1 u8", "[2] w p 1 1 1"):
                (refused,) = await core.execute(s, line)
                assert "ERROR:102 #" in refused and "auth TOKEN" in refused
            assert await core.execute(s, "[3] auth pdo-token-1") == ["[3] OK"]
            assert await core.execute(s, "[4] set tpdo 1 0x201 event 1 u8") == ["[4] OK"]
            core.close()

    asyncio.run(asyncio.wait_for(main(), 60))


# ------------------------------------------------------------------ JSON lines


def test_json_lines_are_a_second_framing_of_the_same_requests() -> None:
    from cobus.apps.gateway import request_line

    assert request_line('{"seq": 1, "node": 5, "command": "r", "args": ["0x1018", 1]}') == (
        "[1] 5 r 0x1018 1"
    )
    assert request_line('{"command": "w", "args": ["Device name", "vs", "a \\"b\\" # c"]}') == (
        'w "Device name" vs "a ""b"" # c"'
    )
    assert request_line("   ") == ""
    for bad in ["[1] r", "{", "[]", '{"command": "r", "colour": 1}', '{"command": 5}',
                '{"command": "r", "args": [true]}', '{"net": 1, "command": "start"}',
                '{"line": "r 1 0", "seq": 1}', '{"command": "w", "args": ["a\\nb"]}']:  # fmt: skip
        refused = request_line(bad)
        assert isinstance(refused, GatewayError) and refused.code == 101, bad

    async def main() -> None:
        rig = Rig.loads(RIG)
        async with AsyncNetwork(interface="virtual", channel=f"gw-{uuid.uuid4()}") as net:
            await rig.start(net)
            server = GatewayServer(GatewayCore({1: net}), json_lines=True)
            await server.start()
            try:
                c = await connect(server)

                async def asked(request: str, count: int = 1) -> list[Any]:
                    return [json.loads(line) for line in await ask(c, request, count)]

                read = '{"seq": 1, "node": 5, "command": "r", "args": ["0x1018", 1, "u32"]}'
                assert await asked(read) == [
                    {
                        "seq": 1,
                        "request": "[1] 5 r 0x1018 1 u32",
                        "ok": True,
                        "value": str(0x00C0B005),
                    }
                ]
                (abort,) = await asked('{"line": "[2] 5 r 0x5FFF 0 u8"}')
                assert abort["seq"] == 2 and abort["ok"] is False
                assert (abort["error"], abort["kind"]) == ("0x06020000", "abort")
                write = '{"node": 5, "command": "w", "args": ["0x1017", "0", "u16", 100]}'
                assert (await asked(write))[0]["ok"] is True
                (value,) = await asked('{"node": 5, "command": "r", "args": ["0x1017", 0, "u16"]}')
                assert value == {"request": "5 r 0x1017 0 u16", "ok": True, "value": "100"}
                (helped,) = await asked('{"command": "help"}')
                assert helped["ok"] is True and "r|read" in helped["lines"][1]
                (bad,) = await asked("not json")
                assert (bad["ok"], bad["error"], bad["kind"]) == (False, 101, "syntax")
                (long,) = await asked("x" * (MAX_LINE + 1))
                assert long["error"] == 101 and "longer than" in long["text"]
                assert (await asked('{"seq": 3, "command": "subscribe"}'))[0]["ok"] is True
                assert (await asked('{"node": 5, "command": "reset", "args": ["node"]}'))[0]["ok"]
                assert json.loads(await c[0].readline()) == {"event": "1 5 BOOT_UP"}
            finally:
                await server.stop()
                await rig.stop()

    asyncio.run(asyncio.wait_for(main(), 60))


# ------------------------------------------------------------------ HTTP (gocanopen's URLs)


def test_http_in_gocanopens_urls_and_a_websocket_of_events() -> None:
    import aiohttp

    from cobus.apps.gateway.http import GatewayHttp

    async def main() -> None:
        rig = Rig.loads(RIG)
        async with AsyncNetwork(interface="virtual", channel=f"gw-{uuid.uuid4()}") as net:
            await rig.start(net)
            core = GatewayCore({1: net}, token="http-token-1")
            http = GatewayHttp(core)
            await http.start()
            base = f"{http.address}/cia309-5/1.0"
            bearer = {"Authorization": "Bearer http-token-1"}
            try:
                async with aiohttp.ClientSession() as client:

                    async def call(
                        method: str, path: str, body: Any = None, **kw: Any
                    ) -> dict[str, Any]:
                        data = None if body is None else json.dumps(body)
                        async with client.request(method, base + path, data=data, **kw) as r:
                            assert r.status == 200 and r.content_type == "application/json"
                            got: dict[str, Any] = await r.json()
                            return got

                    # as gocanopen's client asks: decimal numbers, GET reads, PUT writes
                    got = await call("GET", f"/1/1/5/r/{0x1018}/1")
                    assert got == {"sequence": "1", "response": "OK", "data": "0x00c0b005",
                                   "length": 4}  # fmt: skip
                    write = {"value": "0x00fa", "datatype": "u16"}
                    refused = await call("PUT", "/2/1/5/w/4119/0", write)
                    assert refused["response"] == "ERROR:102" and "auth TOKEN" in refused["text"]
                    ok = await call("PUT", "/3/1/5/w/4119/0", write, headers=bearer)
                    assert ok == {"sequence": "3", "response": "OK"}
                    got = await call("GET", "/4/default/5/r/0x1017/0?datatype=u16")
                    assert got["value"] == "250"
                    abort = await call("GET", "/5/1/5/r/0x5fff/0")
                    assert abort["response"] == "ERROR:0x06020000" and abort["text"]
                    assert (await call("PUT", "/6/1/all/stop", headers=bearer))["response"] == "OK"
                    await asyncio.sleep(0.05)
                    assert device(rig, 6).state is NmtState.STOPPED
                    assert (await call("PUT", "/6/1/0/start", headers=bearer))["response"] == "OK"
                    assert (
                        await call("PUT", "/7/none/none/set/node", {"value": "6"}, headers=bearer)
                    )["response"] == "OK"
                    got = await call("GET", "/8/none/none/r/0x1018/1", {"datatype": "x32"})
                    assert got.get("value") == "0x00C0B005", got  # (node 6, the default now)
                    version = await call("GET", "/9/1/none/info/version")
                    assert version["GatewayClass"] == "3" and version["response"] == "OK"
                    assert (await call("GET", "/10/1/5/frobnicate"))["response"] == "ERROR:100"
                    assert (await call("GET", "/11/1/5/r/0x1018"))["response"] == "ERROR:101"
                    async with client.get(f"{http.address}/x") as r:
                        assert (await r.json())["response"] == "ERROR:101"
                    assert (await call("GET", "/12/1/5/r/1/2", "[1]"))["response"] == "ERROR:101"
                    async with client.get(f"{http.address}/cia309-5/2.0/1/1/5/start") as r:
                        assert (await r.json())["response"] == "ERROR:100"
                    # as gocanopen's client sets the SDO time-out (node all, no content type)
                    timeout = {"value": "0x4c6"}
                    got = await call("PUT", "/14/1/all/set/sdo-timeout", timeout, headers=bearer)
                    assert got["response"] == "OK"
                    got = await call("GET", "/15/1/none/r/0x1017/0")  # (the default node, 6)
                    assert got["data"] == "0x0000"
                    # what a web page could send: refused
                    form = {"Content-Type": "text/plain", **bearer}
                    got = await call("POST", "/16/1/5/w/4119/0", write, headers=form)
                    assert got["response"] == "ERROR:100"
                    got = await call("GET", "/17/1/5/stop", headers=bearer)
                    assert got["response"] == "ERROR:100"
                    evil = {"Origin": "http://evil.example", **bearer}
                    got = await call("PUT", "/18/1/5/stop", headers=evil)
                    assert got["response"] == "ERROR:102" and "evil.example" in got["text"]
                    rebound = {"Host": f"evil.example:{http.port}", **bearer}
                    got = await call("PUT", "/19/1/5/stop", headers=rebound)
                    assert got["response"] == "ERROR:102" and "Host" in got["text"]
                    got = await call("PUT", "/20/1/none/set/node", {"value": "5"})
                    assert got["response"] == "ERROR:102"  # (every client's defaults: token)
                    async with client.post(
                        f"{base}/22/1/5/w/4119/0", json=write, headers=bearer
                    ) as r:
                        assert (await r.json())["response"] == "OK"
                    assert device(rig, 5).state is not NmtState.STOPPED
                    # the events
                    async with client.ws_connect(f"{base}/events") as ws:
                        await asyncio.sleep(0.05)
                        await call("PUT", "/13/1/5/reset/node", headers=bearer)
                        message = await asyncio.wait_for(ws.receive_json(), 5)
                        assert message == {"event": "1 5 BOOT_UP"}
            finally:
                await http.stop()
                await rig.stop()
            with pytest.raises(ValueError, match="token"):
                GatewayHttp(GatewayCore({1: net}), "0.0.0.0")

    asyncio.run(asyncio.wait_for(main(), 60))


def test_lelys_lss_requests() -> None:
    """lss_identity, lss_ident_nonconf, inquiries by Lely's codes, fastscan with masks."""
    from tests.util import simulate

    async def main() -> None:
        rig = Rig.loads("devices:\n  - {node: unconfigured, kind: cia401_io, serial: 0x1234}\n")
        async with AsyncNetwork() as net:
            await rig.start(net)
            core = GatewayCore({1: net}, dialect="lely")
            s = core.session()

            async def say(line: str) -> str:
                (reply,) = await core.execute(s, line)
                return reply

            assert await say("[1] lss_ident_nonconf") == "[1] OK"
            assert await say("[2] lss_identity 0xC0B005 0x191 0 5 0x1000 0x2000") == "[2] OK"
            assert (await say("[3] lss_identity 0xC0B005 0x191 0 5 0 0x1000")).startswith(
                "[3] ERROR: 103 ("
            )
            masks = "0xC0B005 0xFFFFFFFF 0x191 0xFFFFFFFF 0 0 0 0"
            identity = "0x00C0B005 0x00000191 0x00000001 0x00001234"
            assert await say(f"[4] _lss_fastscan {masks}") == f"[4] {identity}"
            assert await say("[5] lss_inquire_addr 0x5D") == "[5] 0x00001234"
            assert await say("[6] lss_inquire_addr 0x5A") == "[6] 0x00C0B005"
            (partial_mask,) = await core.execute(s, "[7] _lss_fastscan 1 0xFF 0 0 0 0 0 0")
            assert partial_mask.startswith("[7] ERROR: 100 (")
            assert (await say("[8] lss_inquire_addr 0x5E")).startswith("[8] ERROR: 101 (")
            assert await say("[9] lss_set_node 9") == "[9] OK"
            assert await say("[10] lss_switch_glob 0") == "[10] OK"
            assert (await say("[11] lss_ident_nonconf")).startswith("[11] ERROR: 103 (")
            # slowscan: the revision, then the serial, halved; the slave found is selected
            found = await say("[12] _lss_slowscan 0xC0B005 0x191 0 5 0 0xFFFF")
            assert found == "[12] 0x00C0B005 0x00000191 0x00000001 0x00001234"
            assert await say("[13] lss_get_node") == "[13] 9"
            none = await say("[14] _lss_slowscan 0xC0B005 0x191 2 5 0 0xFFFF")
            assert none.startswith("[14] ERROR: 103 (")
            backwards = await say("[15] _lss_slowscan 0xC0B005 0x191 5 2 0 1")
            assert backwards.startswith("[15] ERROR: 101 (")
            s.close()
            await rig.stop()

    simulate(main())


#: Lely's coctl documentation, its typical session: the lines cobus's gateway serves (not
#: `set id`, tested apart, and `init`, which re-opens Lely's adapter at another bit rate).
LELY_COCTL = [
    ("[1] set network 1", "[1] OK"),
    ("[2] 2 boot_up_indication Enable", "[2] OK"),
    ("[3] 2 reset node", "[3] OK"),
    (None, "1 2 BOOT_UP"),
    ("[4] set node 2", "[4] OK"),
    ("[5] r 0x1018 0x01 u32", "[5] 0x00000360"),
]


def test_lelys_coctl_session_replayed_line_for_line() -> None:
    from cobus.device import DictionaryBuilder, add_device

    async def main() -> None:
        async with AsyncNetwork(interface="virtual", channel=f"gw-{uuid.uuid4()}") as net:
            add_device(net, 2, DictionaryBuilder(vendor_id=0x360).build())  # (Lely's ID)
            server = GatewayServer(GatewayCore({1: net}, dialect="lely"))
            await server.start()
            try:
                reader, writer = await connect(server)
                for request, documented in LELY_COCTL:
                    if request is not None:
                        writer.write(request.encode() + b"\n")
                    line = await asyncio.wait_for(reader.readline(), 5)
                    assert line.decode().rstrip("\r\n") == documented, request
            finally:
                await server.stop()

    asyncio.run(asyncio.wait_for(main(), 60))


def test_a_heartbeat_watched_with_the_time_a_client_gives() -> None:
    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        c = await connect(server)
        assert await ask(c, "[1] subscribe error_control") == ["[1] OK"]
        assert await ask(c, "[2] 5 enable heartbeat 150") == ["[2] OK"]
        got = await ask(c, "[3] 5 w 0x1017 0 u16 100", 2)
        assert got[0] == "[3] OK" and got[1].endswith("202 (Heartbeat started)")
        started = asyncio.get_running_loop().time()
        got = await ask(c, "[4] 5 w 0x1017 0 u16 0", 2)
        assert got[0] == "[4] OK" and got[1].endswith("203 (Heartbeat lost)")
        assert asyncio.get_running_loop().time() - started < 0.4  # (150 ms, not learned)
        assert await ask(c, "[5] 5 disable heartbeat") == ["[5] OK"]
        assert (await ask(c, "[6] 5 enable guarding 100"))[0].startswith("[6] ERROR:101 #")
        assert (await ask(c, "[7] 5 enable heartbeat"))[0].startswith("[7] ERROR:101 #")

    served(scenario)


def test_what_the_review_of_the_later_slices_found() -> None:
    """Quoting keeps backslashes and several-word values, a tab parts type and value, the
    heartbeat settings need the token, tpdox takes Lely's event<ms>, a TPDO waits for its
    SYNC start value, and an idle timeout set at run time reaches connected clients."""
    from cobus.apps.gateway import request_line
    from cobus.apps.gateway.pdo import parse_pdo_config

    line = request_line('{"command": "w", "args": ["0x2000", 0, "vs", "C:\\\\temp dir"]}')
    assert isinstance(line, str) and parse_value("vs", line.split(None, 4)[4]) == b"C:\\temp dir"
    x = parse_pdo_config(["1", "0x201", "event0", "0", "0"], extended=True)  # (Lely's form)
    assert (x.transmission, x.inhibit_ms, x.event_ms) == (0xFF, 0, 0)
    for words, extended in [(["1", "0x201", "eventually", "0"], False),
                            (["1", "0x201", "event10", "0"], False)]:  # fmt: skip
        with pytest.raises(GatewayError):
            parse_pdo_config(words, extended=extended)

    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        c = await connect(server)
        assert await ask(c, "[1] 5 w 0x1017 0 u16\t1000") == ["[1] OK"]
        assert await ask(c, '[2] 5 w 0x1017 0 hex "e8 03"') == ["[2] OK"]
        assert await ask(c, "[3] 5 r 0x1017 0 u16") == ["[3] 1000"]
        assert await ask(c, "[4] 5 w 0x1017 0 u16 0") == ["[4] OK"]
        sent: list[str] = []
        net.subscribe(0x204, lambda f, now: None if f.rtr else sent.append(f.data.hex()))
        assert await ask(c, "[5] set tpdox 4 0x204 sync2 3 1 u8") == ["[5] OK"]
        assert await ask(c, "[6] w p 4 1 7") == ["[6] OK"]
        for counter in (1, 2, 3, 4, 5, 6):
            net.send(Frame(0x80, bytes([counter])))
        await asyncio.sleep(0.05)
        assert sent == ["07", "07"]  # (at counter 3, then 5)
        # the idle timeout, changed while a client is connected: now it applies
        server.idle_timeout = None
        idle = await connect(server)
        await asyncio.sleep(0.05)
        server.idle_timeout = 0.2
        assert (await asyncio.wait_for(idle[0].readline(), 5)).startswith(b"# idle for 0.2 s")

    served(scenario)

    async def guarded() -> None:
        async with AsyncNetwork(interface="virtual", channel=f"gw-{uuid.uuid4()}") as net:
            core = GatewayCore({1: net}, token="beat-token-1")
            (refused,) = await core.execute(core.session(), "[1] 5 enable heartbeat 100")
            assert refused.startswith("[1] ERROR:102 #") and "auth TOKEN" in refused

    asyncio.run(asyncio.wait_for(guarded(), 30))


#: A value of every data type mnemonic, as a client writes it.
EVERY_TYPE = {
    "b": "1", "i8": "-5", "i16": "-300", "i24": "-70000", "i32": "-100000", "i40": "-2",
    "i48": "-3", "i56": "-4", "i64": "-1234567890123", "u8": "200", "u16": "60000",
    "u24": "70000", "u32": "4000000000", "u40": "5", "u48": "6", "u56": "7",
    "u64": "18446744073709551615", "x8": "0x7f", "x16": "0xBEEF", "x32": "0xDEADBEEF",
    "x64": "0x0123456789ABCDEF", "r32": "1.5", "r64": "2.25", "vs": '"hi ""there"""',
    "os": "AQID", "us": "YQBiAA==", "d": "AAEC", "t": "10 1000", "td": "2 500",
    "hex": "01 02 03",
}  # fmt: skip


@pytest.mark.parametrize("dialect", ["canopennode", "lely"])
def test_every_data_type_through_the_socket_in_both_dialects(dialect: str) -> None:
    """Each type written and read back over TCP: what comes back is what went (the bytes
    the dialect's reply stands for)."""
    from cobus.apps.gateway import TYPES
    from cobus.device import DictionaryBuilder, add_device
    from cobus.od import DataType

    assert set(EVERY_TYPE) == set(TYPES)
    builder = DictionaryBuilder(device_name="every type")
    index = {}
    for i, name in enumerate(EVERY_TYPE):
        data_type = TYPES[name] or DataType.DOMAIN
        index[name] = 0x3000 + i
        builder.variable(0x3000 + i, f"T {name}", data_type, access="rw")

    async def main() -> None:
        async with AsyncNetwork(interface="virtual", channel=f"gw-{uuid.uuid4()}") as net:
            add_device(net, 9, builder.build())
            server = GatewayServer(GatewayCore({1: net}, dialect=dialect))
            await server.start()
            try:
                c = await connect(server)
                for seq, (name, text) in enumerate(EVERY_TYPE.items(), 1):
                    line = f"[{seq}] 9 w 0x{index[name]:04X} 0 {name} {text}"
                    assert await ask(c, line) == [f"[{seq}] OK"], line
                    (reply,) = await ask(c, f"[{seq}] 9 r 0x{index[name]:04X} 0 {name}")
                    value = reply.removeprefix(f"[{seq}] ")
                    assert parse_value(name, value) == parse_value(name, text), (name, reply)
            finally:
                await server.stop()

    asyncio.run(asyncio.wait_for(main(), 60))


def test_the_gateways_token_comes_from_the_option_the_environment_or_chance(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from cobus.apps._serving import gateway_token

    monkeypatch.delenv("COBUS_GATEWAY_TOKEN", raising=False)
    assert gateway_token(None, ["127.0.0.1", "::1"]) == (None, False)
    token, drawn = gateway_token(None, ["127.0.0.1", "0.0.0.0"])
    assert drawn and token is not None and len(token) >= 16
    assert gateway_token("given-token", ["0.0.0.0"]) == ("given-token", False)
    monkeypatch.setenv("COBUS_GATEWAY_TOKEN", "from-the-env")
    assert gateway_token(None, ["127.0.0.1"]) == ("from-the-env", False)
    assert gateway_token("the-option-wins", ["127.0.0.1"]) == ("the-option-wins", False)
    monkeypatch.setenv("COBUS_GATEWAY_TOKEN", "short")
    with pytest.raises(ValueError, match="8 characters"):
        gateway_token(None, ["127.0.0.1"])


# ------------------------------------------------------------------ node guarding


class _GuardedNode:
    """Node 9 on a bus of its own (the same channel): answers node guarding in ``state``
    with the toggle bit, or not at all while ``mute``."""

    def __init__(self, net: AsyncNetwork) -> None:
        self.net = net
        self.state = 0x05
        self.mute = False
        self.toggle = 0
        net.subscribe(0x709, self.on_frame)

    def on_frame(self, frame: Frame, now: float) -> None:
        if frame.rtr and not self.mute:
            self.net.send(Frame(0x709, bytes((self.state | self.toggle << 7,))))
            self.toggle ^= 1


async def _lines(client: Client, count: int, timeout: float = 2.0) -> list[str]:
    reader, _writer = client
    return [
        (await asyncio.wait_for(reader.readline(), timeout)).decode().rstrip("\r\n")
        for _ in range(count)
    ]


def test_a_guarded_node_reports_its_states_a_wrong_one_and_its_loss() -> None:
    """enable guarding: each new state the replies give, 204 when it is not the one the
    gateway's NMT commands asked for, 200 when the replies stop for the life time, and the
    state again when they come back; disable guarding stops the remote requests."""

    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        c = await connect(server)
        assert await ask(c, "[1] subscribe error_control") == ["[1] OK"]
        assert sorted(await ask(c, "[2] 5 enable guarding 50 3", 2)) == [
            "1 5 ERRORx PREO",
            "[2] OK",
        ]
        assert sorted(await ask(c, "[3] 5 start", 2)) == ["1 5 ERRORx OPER", "[3] OK"]
        # the node leaves operational by itself: a wrong state
        device(rig, 5).apply_nmt(0x80)
        assert await _lines(c, 2) == ["1 5 ERROR 204 (Wrong NMT state)", "1 5 ERRORx PREO"]
        # a reset the gateway asked for: pre-operational again is what it expects
        assert sorted(await ask(c, "[4] 5 start", 2)) == ["1 5 ERRORx OPER", "[4] OK"]
        # another master's NMT command on the bus: the state it asks for is no wrong one
        async with AsyncNetwork(interface="virtual", channel=CHANNEL_OF[id(net)]) as master:
            master.send(Frame(0x000, b"\x80\x05"))
            assert await _lines(c, 1) == ["1 5 ERRORx PREO"]
            # new guard times: guarding goes on where it was (no state line again)
            writer = c[1]
            writer.write(b"[40] 5 enable guarding 40 3\n[41] 5 enable guarding 60 3\n")
            assert sorted(await _lines(c, 2)) == ["[40] OK", "[41] OK"]
            master.send(Frame(0x000, b"\x01\x05"))
            assert await _lines(c, 1) == ["1 5 ERRORx OPER"]  # (nothing before it)
        async with AsyncNetwork(interface="virtual", channel=CHANNEL_OF[id(net)]) as other:
            node = _GuardedNode(other)
            assert await ask(c, "[5] 9 enable guarding 40 2", 2) == ["[5] OK", "1 9 ERRORx OPER"]
            node.mute = True
            started = asyncio.get_running_loop().time()
            assert await _lines(c, 1) == ["1 9 ERROR 200 (Lost guarding message)"]
            assert asyncio.get_running_loop().time() - started < 0.3  # (80 ms life time)
            node.mute = False
            assert await _lines(c, 1) == ["1 9 ERRORx OPER"]
            node.state = 0x04
            assert await _lines(c, 2) == ["1 9 ERROR 204 (Wrong NMT state)", "1 9 ERRORx STOP"]
            assert await ask(c, "[6] 9 disable guarding") == ["[6] OK"]
            await asyncio.sleep(0.02)
            asked = node.toggle
            await asyncio.sleep(0.2)
            assert node.toggle == asked  # (no more requests)
            assert await ask(c, "[7] 9 disable guarding") == ["[7] OK"]
        for bad in ["[8] 5 enable guarding 0 3", "[8] 5 enable guarding 50 256",
                    "[8] 5 enable guarding 50", "[8] 5 disable guarding 50"]:  # fmt: skip
            assert (await ask(c, bad))[0].startswith("[8] ERROR:101 #"), bad
        (zero,) = await ask(c, "[9] 0 enable guarding 50 3")
        assert zero.startswith("[9] ERROR:107 #")

    served(scenario)


def test_one_guarding_master_per_node() -> None:
    """A node another master guards is refused (remote requests seen on the bus, or the
    master of this process); another master's requests or the master taking the node over
    stop the gateway's guarding, and its clients are told."""

    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        c = await connect(server)
        assert await ask(c, "[1] subscribe error_control") == ["[1] OK"]
        assert net.claim_guarding(6, "the master") is None
        (refused,) = await ask(c, "[2] 6 enable guarding 50 3")
        assert refused.startswith("[2] ERROR:102 #") and "the master" in refused
        net.release_guarding(6, "the master")
        assert sorted(await ask(c, "[3] 6 enable guarding 50 3", 2))[1] == "[3] OK"
        assert str(net.claim_guarding(6, "a test")).startswith("the CiA 309-3 gateway")
        assert net.claim_guarding(6, "the master", take=True) is None
        (told,) = await _lines(c, 1)
        assert told.startswith("1 6 ERROR 200 (Lost guarding message) #the master guards")
        async with AsyncNetwork(interface="virtual", channel=CHANNEL_OF[id(net)]) as other:
            _GuardedNode(other)
            assert (await ask(c, "[4] 9 enable guarding 40 3", 2))[0] == "[4] OK"
            other.send(Frame(0x709, rtr=True))  # (another master on the bus)
            (told,) = await _lines(c, 1)
            assert told.startswith("1 9 ERROR 200 (Lost guarding message) #")
            assert told.endswith("another master guards it: guarding stopped")
            (again,) = await ask(c, "[5] 9 enable guarding 40 3")
            assert again.startswith("[5] ERROR:102 #") and "another master" in again

    served(scenario)


def test_guarding_needs_the_token() -> None:
    async def main() -> None:
        async with AsyncNetwork(interface="virtual", channel=f"gw-{uuid.uuid4()}") as net:
            core = GatewayCore({1: net}, token="a-long-token")
            session = core.session()
            for line in ("5 enable guarding 50 3", "5 disable guarding"):
                (refused,) = await core.execute(session, line)
                assert refused.startswith("ERROR:102 #") and "auth TOKEN" in refused
            core.close()

    asyncio.run(main())


def test_the_gateway_as_a_device_of_its_own_a_master_guards() -> None:
    """set id N: the gateway is node N (its objects read like any node's), set heartbeat
    produces its heartbeat, a master that stops guarding it is ERROR 201 (Lost connection);
    a node-ID in use, a missing one and a client without the token are refused."""

    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        c = await connect(server)
        assert await ask(c, "[1] subscribe error_control") == ["[1] OK"]
        (no_id,) = await ask(c, "[2] set heartbeat 50")
        assert no_id.startswith("[2] ERROR:102 #") and "set id N" in no_id
        assert await ask(c, "[3] set id 64") == ["[3] OK"]
        assert await ask(c, "[4] 64 r 0x1008 0 vs") == ['[4] "cobus CiA 309-3 gateway"']
        beats: list[float] = []
        net.subscribe(0x740, lambda frame, now: beats.append(now))
        assert await ask(c, "[5] 1 set heartbeat 50") == ["[5] OK"]
        await asyncio.sleep(0.28)
        assert 4 <= len(beats) <= 7 and await ask(c, "[6] 64 r 0x1017 0 u16") == ["[6] 50"]
        assert await ask(c, "[7] set heartbeat 0") == ["[7] OK"]
        # a master guards the gateway, then stops: its life guarding is lost
        assert await ask(c, "[8] 64 w 0x100C 0 u16 40") == ["[8] OK"]
        assert await ask(c, "[9] 64 w 0x100D 0 u8 2") == ["[9] OK"]
        async with AsyncNetwork(interface="virtual", channel=CHANNEL_OF[id(net)]) as master:
            replies: list[bytes] = []
            master.subscribe(0x740, lambda f, now: None if f.rtr else replies.append(f.data))
            for _ in range(3):
                master.send(Frame(0x740, rtr=True))
                await asyncio.sleep(0.03)
            assert [r[0] & 0x7F for r in replies[-3:]] == [0x7F] * 3
            assert [r[0] >> 7 for r in replies[-3:]] == [0, 1, 0]  # (the toggle)
            assert await _lines(c, 1) == ["1 64 ERROR 201 (Lost connection)"]
            master.send(Frame(0x740, rtr=True))
            assert await _lines(c, 1) == ["1 64 ERRORx PREO"]
            assert await _lines(c, 1) == ["1 64 ERROR 201 (Lost connection)"]  # (once more)
            assert await ask(c, "[9] 64 w 0x100D 0 u8 0") == ["[9] OK"]
        # in use: a node heard on the net, a device of this process
        got = await ask(c, "[10] 5 w 0x1017 0 u16 30", 2)
        assert got == ["[10] OK", "1 5 ERRORx PREO 202 (Heartbeat started)"]
        (heard,) = await ask(c, "[11] set id 5")
        assert heard.startswith("[11] ERROR:102 #") and "free node-ID" in heard
        (local,) = await ask(c, "[12] set id 6")
        assert local.startswith("[12] ERROR:102 #node 6 is on net 1 (its error control")
        server.core.in_use[(1, 7)] = "the master's node drive"
        (master_node,) = await ask(c, "[12] set id 7")
        assert "the master's node drive" in master_node
        (own,) = await ask(c, "[13] 64 enable guarding 50 2")
        assert own.startswith("[13] ERROR:102 #") and "the gateway itself" in own
        assert await ask(c, "[14] set id 65") == ["[14] OK"]  # (it moves)
        assert await ask(c, "[15] 65 r 0x1017 0 u16") == ["[15] 0"]
        for bad in ["[16] set id 0", "[16] set id 128", "[16] set heartbeat 70000"]:
            assert (await ask(c, bad))[0].startswith("[16] ERROR:101 #"), bad
        assert await ask(c, "[17] set id 255") == ["[17] OK"]
        (gone,) = await ask(c, "[18] set heartbeat 10")
        assert gone.startswith("[18] ERROR:102 #")
        assert (await ask(c, "[19] 3 set id 5"))[0].startswith("[19] ERROR:106 #")

    served(scenario)


def test_the_gateways_device_needs_the_token() -> None:
    async def main() -> None:
        async with AsyncNetwork(interface="virtual", channel=f"gw-{uuid.uuid4()}") as net:
            core = GatewayCore({1: net}, token="a-long-token")
            session = core.session()
            for line in ("set id 64", "set heartbeat 100"):
                (refused,) = await core.execute(session, line)
                assert refused.startswith("ERROR:102 #") and "auth TOKEN" in refused
            core.close()

    asyncio.run(main())


def test_a_command_time_out_ends_a_request_and_init_is_refused() -> None:
    """set command_timeout: a read the node answers late is ended with ERROR:103 (the
    transfer aborted on the bus), the next one runs; init (Lely's) is refused with how."""

    async def scenario(net: AsyncNetwork, rig: Rig, server: GatewayServer) -> None:
        c = await connect(server)
        aborts: list[bytes] = []
        net.subscribe(0x605, lambda f, now: aborts.append(f.data) if f.data[:1] == b"\x80" else 0)
        device(rig, 5).simulation.sdo_response_delay = 0.3
        assert await ask(c, "[1] set command_timeout 100") == ["[1] OK"]
        (late,) = await ask(c, "[2] 5 r 0x1000 0 u32")
        assert late.startswith("[2] ERROR:103 #") and "100 ms" in late
        await asyncio.sleep(0.35)
        assert aborts  # (the transfer was aborted, not left to the node)
        device(rig, 5).simulation.sdo_response_delay = 0.0
        assert await ask(c, "[3] 5 r 0x1017 0 u16") == ["[3] 0"]
        assert await ask(c, "[4] set command_timeout 0") == ["[4] OK"]
        (bad,) = await ask(c, "[5] set command_timeout 700000")
        assert bad.startswith("[5] ERROR:101 #")
        (init,) = await ask(c, "[6] init 2")
        assert init.startswith("[6] ERROR:100 #") and "lss_conf_bitrate" in init

    served(scenario)


def test_two_servers_of_one_core_and_the_core_closes_with_the_last() -> None:
    """A TCP and a Unix socket server of one core: stopping one leaves the other's clients
    served; the core closes (the buses no longer watched) when the last stops."""

    async def main(tmp: str) -> None:
        async with AsyncNetwork(interface="virtual", channel=f"gw-{uuid.uuid4()}") as net:
            from cobus.device import add_device, minimal_od

            add_device(net, 5, minimal_od())
            core = GatewayCore({1: net})
            tcp, unix = GatewayServer(core), GatewayServer(core, unix=f"{tmp}/gw.sock")
            await tcp.start()
            await unix.start()
            c = await asyncio.open_unix_connection(f"{tmp}/gw.sock")
            assert await ask(c, "[1] subscribe error_control") == ["[1] OK"]
            await tcp.stop()
            assert await ask(c, "[2] 5 r 0x1017 0 u16") == ["[2] 0"]
            assert "[3] OK" in await ask(c, "[3] 5 enable guarding 50 3", 2)
            await unix.stop()
            assert net.guarding_owner(5) is None  # (the core closed: its guard stopped)

    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        asyncio.run(asyncio.wait_for(main(tmp), 60))


def test_slowscan_is_not_fooled_by_a_late_second_slave_and_auth_waits_stay() -> None:
    """Two slaves in the ranges, one answering 3 ms late: _lss_slowscan finds the lowest
    that is there (each answer let settle, the value found asked again); a wrong token's
    wait cut short by cancel does not let the next guess in sooner."""
    import struct as _struct

    async def main() -> None:
        rig = Rig.loads("devices:\n  - {node: unconfigured, kind: cia401_io, serial: 0x1235}\n")
        channel = f"gw-{uuid.uuid4()}"
        async with (
            AsyncNetwork(interface="virtual", channel=channel) as net,
            AsyncNetwork(interface="virtual", channel=channel) as other,
        ):
            await rig.start(net)
            asked: dict[int, int] = {}

            def late_slave(frame: Frame, now: float) -> None:  # (serial 0x1236, 3 ms late)
                cs, value = frame.data[0], _struct.unpack_from("<I", frame.data, 1)[0]
                if 0x46 <= cs <= 0x4B:
                    asked[cs] = value
                within = len(asked) == 6 and asked[0x4A] <= 0x1236 <= value
                if cs == 0x4B and within and asked[0x48] <= 1 <= asked[0x49]:
                    reply = Frame(0x7E4, b"\x4f" + bytes(7))
                    asyncio.get_running_loop().call_later(0.003, other.send, reply)

            other.subscribe(0x7E5, late_slave)
            core = GatewayCore({1: net}, dialect="lely", token="a-long-token")
            s = core.session(trusted=True)
            (found,) = await core.execute(s, "[1] _lss_slowscan 0xC0B005 0x191 0 3 0x1200 0x12FF")
            assert found == "[1] 0x00C0B005 0x00000191 0x00000001 0x00001235"
            guesser = core.session()
            answers: asyncio.Queue[list[str]] = asyncio.Queue()
            core.submit(guesser, "[2] auth not-the-token", answers.put_nowait)
            await asyncio.sleep(0.05)
            (cancelled,) = await core.execute(guesser, "cancel 2")
            assert cancelled.startswith("OK") or cancelled.endswith("OK")
            (early,) = await core.execute(guesser, "[3] auth a-long-token")
            assert early.startswith("[3] ERROR: 102 (") and "less than a second" in early
            core.close()
            await rig.stop()

    asyncio.run(asyncio.wait_for(main(), 60))


def test_a_server_started_twice_listens_once_and_a_failed_bind_leaves_the_core() -> None:
    """From the notes: a GatewayServer started twice lost its first listener; a bind
    that failed left the core watching the buses."""
    import socket

    from cobus.apps.gateway.http import GatewayHttp

    async def main() -> None:
        async with AsyncNetwork(interface="virtual", channel=f"gw-{uuid.uuid4()}") as net:
            core = GatewayCore({1: net})
            server = GatewayServer(core)
            await server.start()
            port = server.port
            await server.start()  # (again: nothing more)
            assert server.port == port and core._held == 1
            client = await asyncio.open_connection("127.0.0.1", port)
            assert await ask(client, "[1] 1 r 0x1000 0 u32") != []
            client[1].close()
            await server.stop()
            assert core._held == 0
            http = GatewayHttp(core)
            await http.start()
            await http.start()
            assert core._held == 1
            await http.stop()
            assert core._held == 0
            with socket.socket() as taken:
                taken.bind(("127.0.0.1", 0))
                taken.listen()
                busy = taken.getsockname()[1]
                for other in (GatewayServer(core, port=busy), GatewayHttp(core, port=busy)):
                    with pytest.raises(OSError):
                        await other.start()
                    assert core._held == 0 and not core._listening

    asyncio.run(asyncio.wait_for(main(), 30))
