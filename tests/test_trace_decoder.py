"""The sans-I/O decoder: frames of the documents decoded one by one, and a whole simulated
session (master booting the thesis servo, SDO reads, an abort, a remapping, a fault)
decoded into records that say what happened."""

from __future__ import annotations

import asyncio
import contextlib
from pathlib import Path
from typing import Any

from cobus.device import export_eds
from cobus.od import loads
from cobus.proto import Frame
from cobus.runtime import AsyncNetwork
from cobus.sim.drive402 import SimulatedDrive402 as Servo
from cobus.trace import (
    Bootup,
    Decoder,
    EmergencyRecord,
    GuardResponse,
    Heartbeat,
    NmtCommandRecord,
    PdoRecord,
    SdoTransfer,
    SyncRecord,
    TimeRecord,
    frame_kind,
)
from cobus.trace.decoder import standard_variable

from .util import simulate


def frame(text: str, rtr: bool = False) -> Frame:
    cob, _, data = text.partition(":")
    if data.strip() == "RTR":
        return Frame(int(cob, 16), b"", rtr=True)
    return Frame(int(cob, 16), bytes.fromhex(data), rtr=rtr)


def decoded(decoder: Decoder, *frames: str, step: float = 0.001) -> list[str]:
    out = []
    for n, text in enumerate(frames):
        out += [str(r) for r in decoder.feed(frame(text), n * step)]
    return out


def test_the_documents_frames_decode_to_what_they_mean() -> None:
    d = Decoder()
    assert decoded(d, "000: 01 08", "000: 81 00", "080:", "080: 05") == [
        "NMT start -> node 8",
        "NMT reset node -> all nodes",
        "SYNC",
        "SYNC 5",
    ]
    # the ZAPI's save: 1010h sub 0 "save", expedited without size, and its answer
    assert decoded(d, "608: 22 10 10 00 73 61 76 65", "588: 60 10 10 00 00 00 00 00") == [
        "node 8 write 1010h:00 Store parameters.Highest sub-index supported = "
        "1702257011 (4 bytes, expedited, 1.0 ms)"
    ]
    assert decoded(d, "708: 00", "708: 05", "708: 7f") == [
        "node 8 boot-up",
        "node 8 heartbeat OPERATIONAL",
        "node 8 heartbeat PRE_OPERATIONAL",
    ]
    assert [str(r) for r in d.feed(frame("709:", rtr=True), 0)] == ["node 9 guarding request"]
    (answer,) = d.feed(frame("709: 85"), 0.01)
    assert isinstance(answer, GuardResponse) and answer.toggle == 1
    assert str(answer) == "node 9 guarding OPERATIONAL (toggle 1)"
    (emcy,) = d.feed(frame("08A: 10 43 09 00 00 00 00 00"), 0)
    assert isinstance(emcy, EmergencyRecord) and emcy.register_bits == ["generic", "temperature"]
    assert (
        str(emcy) == "node 10 EMCY 4310h Temperature (4310h) (register 09h: generic, temperature)"
    )
    carried = emcy.emergency  # the one emergency record of cobus (proto's)
    assert (carried.node_id, carried.code, carried.register) == (10, 0x4310, 0x09)
    assert carried.manufacturer_data == bytes(5) and carried.text == emcy.text
    assert decoded(d, "08A: 00 00 00 00 00 00 00 00") == [
        "node 10 EMCY 0000h error reset (register 00h)"
    ]
    (stamp,) = d.feed(frame("100: 80 EE 36 00 6A 3A"), 0)  # 1984 + 14954 days, 1 h
    assert isinstance(stamp, TimeRecord)
    assert str(stamp) == "TIME 2024-12-10T01:00:00.000+00:00"


def test_segmented_transfers_are_one_record_and_aborts_say_why() -> None:
    d = Decoder()
    read = decoded(
        d,
        "60A: 40 08 10 00 00 00 00 00",
        "58A: 41 08 10 00 0A 00 00 00",  # segmented, 10 bytes
        "60A: 60 00 00 00 00 00 00 00",
        "58A: 00 43 69 41 20 34 30 32",  # "CiA 402"
        "60A: 70 00 00 00 00 00 00 00",
        "58A: 19 20 73 76 00 00 00 00",  # " sv", last (4 bytes unused)
    )
    assert read == [
        "node 10 read 1008h:00 Manufacturer device name = 'CiA 402 sv' "
        "(10 bytes, segmented, 5.0 ms)"
    ]
    write = decoded(
        d,
        "60A: 21 00 20 00 09 00 00 00",  # segmented download, 9 bytes
        "58A: 60 00 20 00 00 00 00 00",
        "60A: 00 01 02 03 04 05 06 07",
        "58A: 20 00 00 00 00 00 00 00",
        "60A: 1B 08 09 00 00 00 00 00",  # toggle 1, 2 bytes, last
        "58A: 30 00 00 00 00 00 00 00",
    )
    assert write == [
        "node 10 write 2000h:00 = 01 02 03 04 05 06 07 08 09 (9 bytes, segmented, 5.0 ms)"
    ]
    aborted = decoded(d, "60A: 40 99 99 00 00 00 00 00", "58A: 80 99 99 00 00 00 02 06")
    assert aborted == [
        "node 10 read 9999h:00 ABORTED 0x06020000 object does not exist in the object "
        "dictionary (1.0 ms)"
    ]


def test_a_simulated_session_decodes_into_what_happened() -> None:
    async def main() -> tuple[list[Any], Decoder]:
        async with AsyncNetwork() as net:
            servo = Servo(net, 10, name="servo")
            od = loads(export_eds(servo.od))
            od.node_id = 10
            decoder = Decoder({10: od})
            records: list[Any] = []
            net.subscribe_all(lambda f, now: records.extend(decoder.feed(f, now)))
            servo.start()
            await asyncio.sleep(0.1)
            node = net.add_remote(10, od)
            await node.sdo.upload(0x1008, 0)
            await node.sdo.download(0x1017, 0, (100).to_bytes(2, "little"))
            with contextlib.suppress(Exception):
                await node.sdo.upload(0x5555, 0)
            # remap TPDO1 to the statusword alone, as a master does, and start the node
            await node.sdo.download(0x1800, 1, (0x8000018A).to_bytes(4, "little"))
            await node.sdo.download(0x1A00, 0, b"\x00")
            await node.sdo.download(0x1A00, 1, (0x60410010).to_bytes(4, "little"))
            await node.sdo.download(0x1A00, 0, b"\x01")
            await node.sdo.download(0x1800, 2, b"\x01")
            await node.sdo.download(0x1800, 1, (0x18A).to_bytes(4, "little"))
            net.nmt.send(0x01, 10)
            net.sync.start(0.01)
            await asyncio.sleep(0.25)
            servo.inject("drive_fault", code=0x7121)
            await asyncio.sleep(0.05)
            net.sync.stop()
            return records, decoder

    records, _ = simulate(main())
    texts = [str(r) for r in records]
    assert any(isinstance(r, Bootup) and r.node == 10 for r in records)
    reads = [r for r in records if isinstance(r, SdoTransfer)]
    name = reads[0]
    assert (name.index, name.write, name.name, name.mode) == (
        0x1008,
        False,
        "Manufacturer device name",
        "segmented",
    )
    assert isinstance(name.value, str) and str(name).startswith(
        "node 10 read 1008h:00 Manufacturer device name = "
    )
    assert (
        "node 10 write 1017h:00 Producer heartbeat time = 100 (2 bytes, expedited"
        in texts[texts.index(str(reads[1]))]
    )
    assert reads[2].abort_code == 0x06020000 and not reads[2].ok
    assert any(isinstance(r, NmtCommandRecord) and r.target == 10 for r in records)
    assert any(isinstance(r, Heartbeat) and r.state == "OPERATIONAL" for r in records)
    assert any(isinstance(r, SyncRecord) for r in records)
    tpdos = [r for r in records if isinstance(r, PdoRecord) and r.cob_id == 0x18A]
    assert tpdos and list(tpdos[-1].values) == ["Statusword"]  # the mapping written: learnt
    assert str(tpdos[-1]).startswith("node 10 TPDO1 Statusword=")
    faults = [r for r in records if isinstance(r, EmergencyRecord)]
    assert faults and faults[0].code == 0x7121 and faults[0].kind == "emcy"


def test_block_transfers_are_put_back_together_with_their_crc_checked() -> None:
    async def main() -> list[Any]:
        async with AsyncNetwork() as net:
            servo = Servo(net, 10, name="servo")
            od = loads(export_eds(servo.od))
            decoder = Decoder({10: od})
            records: list[Any] = []
            net.subscribe_all(lambda f, now: records.extend(decoder.feed(f, now)))
            servo.start()
            await asyncio.sleep(0.1)
            node = net.add_remote(10, od)
            eds = await node.sdo.upload(0x1021, 0, block=True)  # the stored EDS, kilobytes
            with contextlib.suppress(Exception):  # read-only: the server aborts the block
                await node.sdo.download(0x1008, 0, b"x" * 30, block=True)
            return [eds, *records]

    eds, *records = simulate(main())
    transfers = [r for r in records if isinstance(r, SdoTransfer)]
    assert [(r.index, r.write, r.mode) for r in transfers] == [
        (0x1021, False, "block"),
        (0x1008, True, "aborted"),
    ]
    assert transfers[0].data == eds and len(eds) > 1000
    text = str(transfers[0])
    assert text.startswith("node 10 read 1021h:00 Store EDS = b'[FileInfo]")
    assert text.endswith(f"... ({len(eds)} bytes, block, 0.0 ms)")
    assert transfers[1].abort_code == 0x06010002
    assert str(transfers[1]).startswith("node 10 write 1008h:00 Manufacturer device name ABORTED")


def test_a_block_upload_frame_by_frame_with_a_wrong_crc_and_a_retransmission() -> None:
    d = Decoder()
    out = decoded(
        d,
        "60A: A4 21 10 00 7F 00 00 00",  # initiate block upload, CRC, 127 segments
        "58A: C6 21 10 00 0A 00 00 00",  # 10 bytes
        "60A: A3 00 00 00 00 00 00 00",  # start
        "58A: 01 30 31 32 33 34 35 36",
        "58A: 82 37 38 39 00 00 00 00",  # last segment ... lost on the way, say
        "60A: A2 01 7F 00 00 00 00 00",  # only segment 1 acknowledged
        "58A: 82 37 38 39 00 00 00 00",  # sent again
        "60A: A2 02 7F 00 00 00 00 00",
        "58A: D1 34 12 00 00 00 00 00",  # end: 4 bytes unused, CRC 1234h
        "60A: A1 00 00 00 00 00 00 00",
    )
    assert len(out) == 1
    assert out[0].startswith("node 10 read 1021h:00 Store EDS = b'0123456789' (10 bytes, ")
    assert "block, CRC 1234h WRONG (data gives " in out[0]


def test_per_node_figures_latency_jitter_missed_beats_and_a_time_line() -> None:
    d = Decoder()
    for t, text in [
        (0.0, "70A: 00"),
        (0.05, "60A: 40 17 10 00 00 00 00 00"),
        (0.052, "58A: 4B 17 10 00 64 00 00 00"),
        (0.1, "70A: 7F"),
        (0.2, "70A: 7F"),
        (0.3, "70A: 7F"),
        (0.41, "70A: 05"),
        (0.5, "08A: 10 43 09 00 00 00 00 00"),
        (0.71, "70A: 05"),  # two beats missing (0.51, 0.61)
    ]:
        d.feed(frame(text), t)
    stats = d.stats[10]
    latency = stats.sdo_latency
    assert latency is not None and abs(latency[1] - 0.002) < 1e-9
    assert stats.heartbeats == 5 and stats.missed_beats == 2
    assert stats.heartbeat_period is not None and abs(stats.heartbeat_period - 0.11) < 1e-9
    assert stats.jitter is not None and abs(stats.jitter - 0.19) < 1e-9
    assert [text for _, text in stats.timeline] == [
        "BOOTUP",
        "PRE_OPERATIONAL",
        "OPERATIONAL",
        "EMCY 4310h",
    ]
    summary = stats.summary()
    assert summary["emcy_count"] == 1 and summary["state"] == "OPERATIONAL"
    assert summary["last_emcy"].startswith("EMCY 4310h Temperature")


def test_hostile_and_partial_traces_from_a_review() -> None:
    d = Decoder()
    # pre-defined PDOs: direction and number from the COB-ID
    assert decoded(d, "205: 01", "285: 02", "385: 03", "4FF: 04") == [
        "node 5 RPDO1 01",
        "node 5 TPDO2 02",
        "node 5 TPDO3 03",
        "node 127 TPDO4 04",
    ]
    # a client abort inside a block download sub-block is an abort, and the next transfer
    # is its own
    out = decoded(
        d,
        "605: C6 00 20 00 0A 00 00 00",
        "585: A4 00 20 00 7F 00 00 00",
        "605: 01 30 31 32 33 34 35 36",
        "605: 80 00 20 00 00 00 04 05",
        "605: 2B 17 10 00 64 00 00 00",
        "585: 60 17 10 00 00 00 00 00",
    )
    assert out[0].startswith("node 5 write 2000h:00 ABORTED 0x05040000")
    assert out[1].startswith(
        "node 5 write 1017h:00 Producer heartbeat time = 100 (2 bytes, expedited"
    )
    # a trace that starts mid-block invents no abort; an answer without its request is kept
    assert decoded(d, "585: 82 37 38 39 00 00 00 00") == []
    assert decoded(d, "585: 43 18 10 01 11 22 33 44")[0].startswith(
        "node 5 read 1018h:01 Identity object.Vendor-ID = 1144201745 "
        "(4 bytes, expedited, request not seen"
    )
    # an answer about another object than asked is not taken for it
    out = decoded(d, "605: 40 08 10 00 00 00 00 00", "585: 43 18 10 01 11 22 33 44")
    assert out == [
        "node 5 read 1018h:01 Identity object.Vendor-ID = 1144201745 "
        "(4 bytes, expedited, request not seen, 0.0 ms)"
    ]
    # a repeated segment (same toggle) is not data; a size that disagrees is said
    out = decoded(
        d,
        "605: 40 08 10 00 00 00 00 00",
        "585: 41 08 10 00 0B 00 00 00",
        "605: 60 00 00 00 00 00 00 00",
        "585: 00 43 69 41 20 34 30 32",
        "585: 00 43 69 41 20 34 30 32",  # again, toggle 0
        "605: 70 00 00 00 00 00 00 00",
        "585: 19 20 73 76 00 00 00 00",
    )
    assert out == [
        "node 5 read 1008h:00 Manufacturer device name = 'CiA 402 sv' (10 bytes, segmented, "
        "11 bytes announced, 6.0 ms)"
    ]
    # the same for a download: a segment sent again with the toggle bit of the last one
    # (the client repeating it) is not data
    out = decoded(
        d,
        "605: 21 00 20 00 09 00 00 00",
        "585: 60 00 20 00 00 00 00 00",
        "605: 00 01 02 03 04 05 06 07",
        "605: 00 01 02 03 04 05 06 07",  # again, toggle 0
        "585: 20 00 00 00 00 00 00 00",
        "605: 1B 08 09 00 00 00 00 00",
        "585: 30 00 00 00 00 00 00 00",
    )
    assert out == [
        "node 5 write 2000h:00 = 01 02 03 04 05 06 07 08 09 (9 bytes, segmented, 6.0 ms)"
    ]
    # a transfer the trace ends in is reported by flush()
    decoded(d, "605: 40 09 10 00 00 00 00 00")
    assert [str(r) for r in d.flush(1.0)] == [
        "node 5 read 1009h:00 Manufacturer hardware version = (no data) "
        "(0 bytes, incomplete, 1000.0 ms)"
    ]
    # a state frame answers guarding only right after the master's request
    d.feed(frame("705:", rtr=True), 2.0)
    assert decoded(d, "705: 85") == ["node 5 guarding OPERATIONAL (toggle 1)"]
    assert decoded(d, "705: 05") == ["node 5 heartbeat OPERATIONAL"]


def test_lss_frames_in_words_and_sessions_as_sentences() -> None:
    d = Decoder()
    out = decoded(
        d,
        "7E5: 40 60 03 00 00 00 00 00",  # switch selective: vendor, product, revision, serial
        "7E5: 41 34 12 00 00 00 00 00",
        "7E5: 42 00 00 01 00 00 00 00",
        "7E5: 43 2A 00 00 00 00 00 00",
        "7E4: 44 00 00 00 00 00 00 00",
        "7E5: 11 0C 00 00 00 00 00 00",  # configure node-ID 12
        "7E4: 11 00 00 00 00 00 00 00",
        "7E5: 13 00 03 00 00 00 00 00",  # 250 kbit/s
        "7E4: 13 00 00 00 00 00 00 00",
        "7E5: 17 00 00 00 00 00 00 00",  # store: a media error
        "7E4: 17 02 00 00 00 00 00 00",
        "7E5: 15 64 00 00 00 00 00 00",  # activate after 100 ms: no answer
        "7E5: 04 00 00 00 00 00 00 00",
    )
    who = "serial 0x0000002A (vendor-ID 0x00000360, product code 0x00001234, revision 0x00010000)"
    assert out == [
        "LSS master switch state selective: vendor-ID 0x00000360",
        "LSS master switch state selective: product code 0x00001234",
        "LSS master switch state selective: revision 0x00010000",
        "LSS master switch state selective: serial 0x0000002A",
        "LSS slave answer: selected (configuration state)",
        f"LSS: {who} selected (configuration state)",
        "LSS master configure node-ID 12",
        "LSS slave answer: node-ID configured",
        f"LSS: {who} got node-ID 12",
        "LSS master configure bit timing: 250 kbit/s",
        "LSS slave answer: bit timing accepted",
        f"LSS: {who} will use 250 kbit/s once activated",
        "LSS master store configuration",
        "LSS slave answer: not stored: storage media access error",
        f"LSS: {who} could not store its configuration: storage media access error",
        "LSS master activate bit timing after 100 ms",
        "LSS master switch state global: waiting",
    ]
    # A fastscan: the reset, then each field confirmed (bits scanned in between say nothing).
    out = decoded(
        d,
        "7E5: 51 00 00 00 00 80 00 00",
        "7E4: 4F 00 00 00 00 00 00 00",
        "7E5: 51 00 00 00 80 1F 00 00",  # bit 31 of the vendor-ID: nobody answers
        "7E5: 51 60 03 00 00 00 00 01",
        "7E4: 4F 00 00 00 00 00 00 00",
        "7E5: 51 34 12 00 00 00 01 02",
        "7E4: 4F 00 00 00 00 00 00 00",
        "7E5: 51 00 00 01 00 00 02 03",
        "7E4: 4F 00 00 00 00 00 00 00",
        "7E5: 51 2B 00 00 00 00 03 00",
        "7E4: 4F 00 00 00 00 00 00 00",
        "7E5: 5E 00 00 00 00 00 00 00",
        "7E4: 5E FF 00 00 00 00 00 00",
        "7E5: 11 C8 00 00 00 00 00 00",  # 200: out of range
        "7E4: 11 01 00 00 00 00 00 00",
        step=0.01,
    )
    who = who.replace("2A", "2B")
    sentences = [line for line in out if line.startswith("LSS: ")]
    assert sentences == [
        f"LSS: fastscan found {who}, now in configuration state",
        f"LSS: {who} has no node-ID (unconfigured)",
        f"LSS: {who} refused node-ID 200: out of range",
    ]
    assert out[0] == "LSS master fastscan: reset, every non-configured slave answer"
    assert out[2] == "LSS master fastscan: vendor-ID 0x80000000, bits 31..31"
    # After a global switch the slave is not known by identity; an answer a second late is
    # no answer; a frame of a kind the decoder does not know keeps its bytes.
    out = decoded(
        d,
        "7E5: 04 01 00 00 00 00 00 00",
        "7E5: 11 05 00 00 00 00 00 00",
        "7E4: 11 00 00 00 00 00 00 00",
        "7E5: 11 06 00 00 00 00 00 00",
        "7E5: 99 01 02",
        step=0.6,
    )
    assert out == [
        "LSS master switch state global: configuration",
        "LSS master configure node-ID 5",
        "LSS slave answer: node-ID configured",
        "LSS: the slave in configuration state got node-ID 5",
        "LSS master configure node-ID 6",
        "LSS master cs 99h 01 02 (a short frame: 3 of 8 bytes)",
    ]
    assert d.feed(frame("7E4: 11 00 00 00 00 00 00 00"), 10.0)[1:] == []  # too late
    assert {r.kind for r in d.feed(frame("7E4: 5A 01 00 00 00 00 00 00"), 11.0)} == {"lss"}


def test_guarding_toggle_errors_are_records_and_counted() -> None:
    d = Decoder()
    out = decoded(
        d,
        "705: 00",  # boot-up: the first answer carries toggle 0
        "705: RTR",
        "705: 7F",
        "705: RTR",
        "705: FF",
        "705: RTR",
        "705: FF",  # toggle 1 again
        "705: RTR",
        "705: 05",
    )
    assert out[2] == "node 5 guarding PRE_OPERATIONAL (toggle 0)"
    assert out[4] == "node 5 guarding PRE_OPERATIONAL (toggle 1)"
    assert out[6] == "node 5 guarding PRE_OPERATIONAL (toggle 1, TOGGLE ERROR: not alternated)"
    assert out[8] == "node 5 guarding OPERATIONAL (toggle 0)"
    stats = d.stats[5]
    assert stats.toggle_errors == 1 and stats.summary()["toggle_errors"] == 1
    assert any(text == "guarding toggle error" for _, text in stats.timeline)
    # A boot-up starts the toggle again; a wrong first toggle after it is an error.
    assert decoded(d, "705: 00", "705: RTR", "705: FF")[-1].endswith(
        "TOGGLE ERROR: not alternated)"
    )
    # Without a boot-up seen (the trace began mid-run), the first answer sets the rhythm.
    d2 = Decoder()
    assert "ERROR" not in " ".join(decoded(d2, "706: RTR", "706: 85", "706: RTR", "706: 05"))


def test_cia301_objects_have_their_names_and_types_without_an_eds() -> None:
    d = Decoder()
    out = decoded(
        d,
        "605: 40 18 10 04 00 00 00 00",
        "585: 43 18 10 04 2A 00 00 00",
        "605: 23 03 1A 05 20 00 64 60",  # TPDO4's fifth mapped object
        "585: 60 03 1A 05 00 00 00 00",
        "605: 40 03 10 07 00 00 00 00",
        "585: 43 03 10 07 10 81 00 00",
        "605: 40 00 20 00 00 00 00 00",  # a manufacturer object: no name
        "585: 4F 00 20 00 07 00 00 00",
        "605: 2B 17 10 00 64 00 00 00",  # 1017h written with 2 bytes as CiA 301 types it
        "585: 60 17 10 00 00 00 00 00",
        "605: 23 17 10 00 64 00 00 00",  # ... and with 4: its bytes as they came
        "585: 60 17 10 00 00 00 00 00",
    )
    assert [line.split(" (")[0] for line in out] == [
        "node 5 read 1018h:04 Identity object.Serial number = 42",
        "node 5 write 1A03h:05 TPDO mapping parameter 4.Mapped object 5 = 1617166368",
        "node 5 read 1003h:07 Pre-defined error field.Standard error field 7 = 33040",
        "node 5 read 2000h:00 = 7",
        "node 5 write 1017h:00 Producer heartbeat time = 100",
        "node 5 write 1017h:00 Producer heartbeat time = 100",
    ]
    assert standard_variable(0x1018, 5) is None and standard_variable(0x2000, 0) is None
    var = standard_variable(0x1405, 2)
    assert var is not None and var.name == "RPDO communication parameter 6.Transmission type"


def test_frame_kind_is_the_service_of_the_predefined_connection_set() -> None:
    kinds = {
        0x000: "nmt",
        0x080: "sync",
        0x085: "emcy",
        0x100: "time",
        0x185: "pdo",
        0x57F: "pdo",
        0x585: "sdo",
        0x605: "sdo",
        0x705: "hb",
        0x7E4: "lss",
        0x7E5: "lss",
        0x680: "other",
        0x700: "other",
    }
    assert {cob: frame_kind(Frame(cob, b"")) for cob in kinds} == kinds
    assert frame_kind(Frame(0x185, b"", extended=True)) == "other"


def test_a_network_file_names_and_scales_the_pdo_signals() -> None:
    """With the master's network file the decoder shows its signals (the master's names,
    scale, unit) for
    the mapping the file configures; a mapping changed on the bus is learnt, and the file's
    names come back once the bus sets the file's mapping again."""
    from pathlib import Path

    from cobus.master import load_network

    network = load_network(Path(__file__).parent.parent / "examples/networks/line.yml")
    d = Decoder(network=network)
    position = (1234).to_bytes(4, "little", signed=True)
    assert decoded(d, "183: 37 06 " + position.hex(" ")) == [
        "node 3 TPDO1 drive1.statusword=1591, drive1.position=1.234 mm"
    ]
    assert decoded(d, "203: 0F 00 " + (-500).to_bytes(4, "little", signed=True).hex(" ")) == [
        "node 3 RPDO1 drive1.controlword=15, drive1.target=-0.5 mm"
    ]
    (rec,) = d.feed(frame("182: 05 0A"), 1.0)
    assert isinstance(rec, PdoRecord) and dict(rec.values) == {
        "io1.inputs_low": 5,
        "io1.inputs_high": 10,
    }
    # Someone maps only the statusword into TPDO1 (count 0, entry, count 1): learnt ...
    remap = [
        "603: 2F 00 1A 00 00 00 00 00",
        "583: 60 00 1A 00 00 00 00 00",
        "603: 23 00 1A 01 10 00 41 60",
        "583: 60 00 1A 01 00 00 00 00",
        "603: 2F 00 1A 00 01 00 00 00",
        "583: 60 00 1A 00 00 00 00 00",
    ]
    decoded(d, *remap)
    assert decoded(d, "183: 37 06")[0].startswith("node 3 TPDO1 ")
    assert "position" not in decoded(d, "183: 37 06")[0]
    # ... and the file's mapping written back brings its signals back.
    back = [
        "603: 2F 00 1A 00 00 00 00 00",
        "583: 60 00 1A 00 00 00 00 00",
        "603: 23 00 1A 02 20 00 64 60",
        "583: 60 00 1A 02 00 00 00 00",
        "603: 2F 00 1A 00 02 00 00 00",
        "583: 60 00 1A 00 00 00 00 00",
    ]
    decoded(d, *back)
    assert decoded(d, "183: 37 06 " + position.hex(" ")) == [
        "node 3 TPDO1 drive1.statusword=1591, drive1.position=1.234 mm"
    ]


def test_the_cia402_state_goes_on_the_node_time_line() -> None:
    """A statusword in a TPDO (as the EDS maps it) or read over SDO puts the drive's power
    state beside its NMT states and emergencies."""
    from pathlib import Path

    from cobus.master import load_network

    network = load_network(Path(__file__).parent.parent / "examples/networks/line.yml")
    d = Decoder(network=network)
    decoded(
        d,
        "703: 7F",
        "183: 40 02 00 00 00 00",  # switch on disabled
        "183: 37 02 00 00 00 00",  # operation enabled
        "183: 37 02 10 00 00 00",  # (the same state: no new entry)
        "083: 10 23 01 00 00 00 00 00",
        "603: 40 41 60 00 00 00 00 00",
        "583: 4B 41 60 00 08 02 00 00",  # fault, read over SDO
    )
    stats = d.stats[3]
    assert [text for _, text in stats.timeline] == [
        "PRE_OPERATIONAL",
        "CiA 402 SWITCH_ON_DISABLED",
        "CiA 402 OPERATION_ENABLED",
        "EMCY 2310h",
        "CiA 402 FAULT",
    ]
    assert stats.drive_state == "FAULT" and stats.summary()["drive_state"] == "FAULT"


def test_review_fixes_lss_toggle_and_axes() -> None:
    d = Decoder()
    # A master checking bit 0 (BitChecked 0, LSSNext = LSSSub) is scanning, not confirming.
    out = decoded(
        d,
        "7E5: 51 2A 00 00 00 00 03 03",
        "7E4: 4F 00 00 00 00 00 00 00",
        "7E5: 51 2A 00 00 00 00 03 00",
        "7E4: 4F 00 00 00 00 00 00 00",
    )
    assert out[0] == "LSS master fastscan: serial 0x0000002A, bits 31..0"
    assert [x for x in out if x.startswith("LSS: ")] == [
        "LSS: fastscan found serial 0x0000002A, now in configuration state"
    ]
    # Short LSS frames are said to be short and make no sentence.
    out = decoded(d, "7E5: 11", "7E4: 11")
    assert out == [
        "LSS master cs 11h (a short frame: 1 of 8 bytes)",
        "LSS slave cs 11h (a short frame: 1 of 8 bytes)",
    ]
    # An NMT reset starts the guarding toggle again; a late answer (a heartbeat) forgets it.
    guard = decoded(d, "705: 00", "705: RTR", "705: 7F", "705: RTR", "705: FF", "000: 82 05")
    assert "ERROR" not in " ".join(guard)
    assert "ERROR" not in decoded(d, "705: RTR", "705: 7F")[-1]
    decoded(d, "705: RTR", "705: FF")
    d.feed(frame("705: RTR"), 10.0)
    assert str(d.feed(frame("705: 7F"), 12.0)[0]) == "node 5 heartbeat PRE_OPERATIONAL"
    assert "ERROR" not in str(d.feed(frame("705: RTR"), 13.0)[0]) + str(
        d.feed(frame("705: FF"), 13.01)[0]
    )
    # Two axes: each axis keeps its own state, the time line only changes.
    od = loads(export_eds(_two_axis_od()), node_id=7)
    d2 = Decoder({7: od})
    for _ in range(3):
        decoded(d2, "187: 37 06", "287: 40 02")
    entries = [text for _, text in d2.stats[7].timeline]
    assert entries == ["CiA 402 OPERATION_ENABLED", "CiA 402 axis 2 SWITCH_ON_DISABLED"]
    assert d2.stats[7].drive_states == {1: "OPERATION_ENABLED", 2: "SWITCH_ON_DISABLED"}


def _two_axis_od() -> Any:
    from cobus.device import DictionaryBuilder
    from cobus.od import Access, DataType

    b = DictionaryBuilder(device_name="two axes", node_id=7)
    b.variable(0x6041, "Statusword", DataType.UNSIGNED16, access=Access.RO, mappable=True)
    b.variable(0x6841, "Statusword axis 2", DataType.UNSIGNED16, access=Access.RO, mappable=True)
    b.tpdo(1, [(0x6041, 0)])
    b.tpdo(2, [(0x6841, 0)])
    return b.build()


def test_a_network_file_pdo_moved_or_linked_keeps_the_right_names() -> None:
    from pathlib import Path

    from cobus.master import load_network

    network = load_network(Path(__file__).parent.parent / "examples/networks/line.yml")
    d = Decoder(network=network)
    # drive1's TPDO1 moved from 183h to 193h by SDO: still its signals, scaled.
    decoded(
        d,
        "603: 23 00 18 01 83 01 00 80",
        "583: 60 00 18 01 00 00 00 00",
        "603: 23 00 18 01 93 01 00 00",
        "583: 60 00 18 01 00 00 00 00",
    )
    position = (1234).to_bytes(4, "little").hex(" ")
    assert decoded(d, "193: 37 06 " + position) == [
        "node 3 TPDO1 drive1.statusword=1591, drive1.position=1.234 mm"
    ]


def test_a_linked_rpdo_of_a_network_file_leaves_the_frame_to_the_tpdo(tmp_path: Path) -> None:
    """drive1's RPDO1 listens to io1's TPDO1 (PDO linking): the frame is io1's inputs."""
    from cobus.master import load_network

    folder = Path(__file__).parent.parent / "examples/networks"
    text = (folder / "line.yml").read_text()
    text = text.replace("eds: devices/", f"eds: {folder}/devices/")
    text = text.replace(
        "      mapping: [controlword, target_position]\n      transmission_type: 1",
        "      mapping: [controlword]\n      transmission_type: 255\n      cob_id: 0x182",
    )
    text = text.replace("      target: {object: target_position, scale: 0.001, unit: mm}\n", "")
    (tmp_path / "linked.yml").write_text(text)
    d = Decoder(network=load_network(tmp_path / "linked.yml"))
    assert decoded(d, "182: 12 34") == ["node 2 TPDO1 io1.inputs_low=18, io1.inputs_high=52"]


def test_a_cia402_drive_s_emergencies_have_the_cia402_texts() -> None:
    """Issue 38 (9): a drive's EMCY codes got the generic CiA 301 class texts."""
    emcy = Frame(0x08A, bytes([0x05, 0x73, 0x81, 0, 0, 0, 0, 0]))  # 7305h, node 10
    plain = Decoder()
    (generic,) = plain.feed(emcy, 0.0)
    assert isinstance(generic, EmergencyRecord) and generic.text == "Additional modules (7305h)"
    # the decoder learns the profile from a read of 1000h on the bus ...
    plain.feed(Frame(0x60A, bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0])), 0.1)
    plain.feed(Frame(0x58A, bytes([0x43, 0x00, 0x10, 0, 0x92, 0x01, 0x02, 0x00])), 0.2)
    (drive,) = plain.feed(emcy, 0.3)
    assert isinstance(drive, EmergencyRecord) and drive.text == "Incremental sensor 1 fault"
    assert "EMCY 7305h Incremental sensor 1 fault" in str(drive)
    # ... or from the node's EDS
    od = loads(_servo_eds())
    (known,) = Decoder({10: od}).feed(emcy, 0.0)
    assert isinstance(known, EmergencyRecord) and known.text == "Incremental sensor 1 fault"
    # another node's stays CiA 301's
    (other,) = Decoder({10: od}).feed(Frame(0x08B, emcy.data), 0.0)
    assert isinstance(other, EmergencyRecord) and other.text == "Additional modules (7305h)"


def _servo_eds() -> str:
    async def export() -> str:
        async with AsyncNetwork() as net:
            return export_eds(Servo(net, 10).od)

    return simulate(export())
