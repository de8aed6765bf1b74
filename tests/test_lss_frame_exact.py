"""cobus's LSS master against a slave written here from CiA 305's tables alone (no cobus
code): a python-can bus of its own on the same virtual channel, answering every service byte
for byte, in real time. python-canopen has no LSS slave to be the peer, so this one is."""

from __future__ import annotations

import os
import struct
import threading
from collections.abc import Iterator

import can
import pytest

from cobus.proto.lss import LssError, LssIdentity, LssState
from cobus.runtime import LssRefusedError, Network

# CiA 305 command specifiers, written out from the standard's tables (not imported)
REQ, RES = 0x7E5, 0x7E4
IDENT = (0x360, 0x0007_0001, 0x0003_0002, 0x8BAD_F00D)


class TableSlave(can.Listener):
    """One LSS slave, frame by frame: switch state global (04h) and selective (40h-43h ->
    44h), configure node-ID (11h), bit timing (13h), activate (15h), store (17h), inquire
    (5Ah-5Eh), identify remote (46h-4Bh -> 4Fh), identify non-configured (4Ch -> 50h) and
    fastscan (51h -> 4Fh)."""

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self.node_id = 0xFF
        self.pending = 0xFF
        self.config = False
        self.timing: int | None = None
        self.activated: list[int] = []
        self.stored: list[tuple[int, int | None]] = []
        self.sel: list[int] = []
        self.ranges: list[int] = []
        self.lss_pos = 0
        self.requests: list[bytes] = []

    def answer(self, *data: int) -> None:
        body = bytes(data) + bytes(8 - len(data))
        self.bus.send(can.Message(arbitration_id=RES, data=body, is_extended_id=False))

    def on_message_received(self, msg: can.Message) -> None:
        if msg.arbitration_id != REQ or msg.is_extended_id or len(msg.data) != 8:
            return
        d = bytes(msg.data)
        self.requests.append(d)
        cs = d[0]
        value = struct.unpack_from("<I", d, 1)[0]
        if cs == 0x04:
            if d[1] == 0 and self.config and self.node_id == 0xFF and self.pending != 0xFF:
                self.node_id = self.pending  # an unconfigured slave boots at once
            self.config = d[1] == 1
        elif 0x40 <= cs <= 0x43:
            self.sel = [*self.sel, value] if cs - 0x40 == len(self.sel) else []
            if len(self.sel) == 4:
                if tuple(self.sel) == IDENT:
                    self.config = True
                    self.answer(0x44)
                self.sel = []
        elif 0x46 <= cs <= 0x4B:
            self.ranges = [*self.ranges, value] if cs - 0x46 == len(self.ranges) else []
            if len(self.ranges) == 6:
                v, p, rl, rh, sl, sh = self.ranges
                if (v, p) == IDENT[:2] and rl <= IDENT[2] <= rh and sl <= IDENT[3] <= sh:
                    self.answer(0x4F)
                self.ranges = []
        elif cs == 0x4C:
            if self.node_id == 0xFF and self.pending == 0xFF:
                self.answer(0x50)
        elif cs == 0x51:
            self.fastscan(value, d[5], d[6], d[7])
        elif not self.config:
            return
        elif cs == 0x11:
            ok = 1 <= d[1] <= 127 or d[1] == 0xFF
            if ok:
                self.pending = d[1]
            self.answer(0x11, 0 if ok else 1)
        elif cs == 0x13:
            ok = d[1] == 0 and d[2] in (0, 2, 3, 4)  # 1000, 500, 250, 125 kbit/s
            if ok:
                self.timing = d[2]
            self.answer(0x13, 0 if ok else 1)
        elif cs == 0x15:
            self.activated.append(struct.unpack_from("<H", d, 1)[0])
        elif cs == 0x17:
            self.stored.append((self.pending, self.timing))
            self.answer(0x17, 0)
        elif 0x5A <= cs <= 0x5D:
            self.answer(cs, *struct.pack("<I", IDENT[cs - 0x5A]))
        elif cs == 0x5E:
            self.answer(0x5E, self.node_id)

    def fastscan(self, number: int, bit: int, sub: int, nxt: int) -> None:
        if self.node_id != 0xFF or self.pending != 0xFF or self.config:
            return
        if bit == 0x80:
            self.lss_pos = 0
            self.answer(0x4F)
            return
        if bit > 31 or sub != self.lss_pos:
            return
        mask = (0xFFFFFFFF << bit) & 0xFFFFFFFF
        if (IDENT[sub] ^ number) & mask:
            return
        self.lss_pos = nxt
        if bit == 0 and nxt < sub:
            self.config = True
        self.answer(0x4F)


def in_config(slave: TableSlave) -> bool:
    return slave.config


@pytest.fixture
def peer() -> Iterator[tuple[str, TableSlave]]:
    channel = f"lss-table-{os.getpid()}-{threading.get_ident()}"
    bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    slave = TableSlave(bus)
    notifier = can.Notifier(bus, [slave], timeout=0.01)
    try:
        yield channel, slave
    finally:
        notifier.stop()
        bus.shutdown()


def test_every_lss_service_of_cobus_against_a_slave_from_the_tables(
    peer: tuple[str, TableSlave],
) -> None:
    channel, slave = peer
    ident = LssIdentity(*IDENT)
    with Network(interface="virtual", channel=channel) as net:
        net.lss.timeout = 0.2
        assert net.lss.identify_unconfigured()
        assert net.lss.identify_remote(IDENT[0], IDENT[1], (0, IDENT[2]), (IDENT[3], 0xFFFFFFFF))
        assert not net.lss.identify_remote(IDENT[0], IDENT[1], (0, 1), (0, 0xFFFFFFFF))
        found = net.lss.fastscan({"vendor": IDENT[0]}, floor=0.005, ceiling=0.2)
        assert found == ident, found
        assert in_config(slave)
        assert net.lss.inquire_identity() == ident
        assert net.lss.inquire("node_id") == 0xFF
        with pytest.raises(LssError):
            net.lss.configure_node_id(0)  # refused before it is sent
        net.lss.configure_node_id(42)
        with pytest.raises(LssRefusedError, match="not supported"):
            net.lss.configure_bit_rate(800)  # index 1: not in this slave's table
        net.lss.configure_bit_rate(250)
        net.lss.store()
        assert slave.stored == [(42, 3)]
        net.lss.activate_bit_rate(0.1)
        net.lss.switch_global(LssState.WAITING)
        net.sleep(0.1)
        assert slave.activated == [100] and slave.node_id == 42 and not in_config(slave)
        net.lss.select(ident)
        assert in_config(slave) and net.lss.inquire("node_id") == 42
        net.lss.switch_global(LssState.WAITING)
        net.sleep(0.05)
    # what cobus sent, byte for byte, for the services with fixed frames
    sent = slave.requests
    assert bytes([0x4C, 0, 0, 0, 0, 0, 0, 0]) in sent
    assert bytes([0x51, 0, 0, 0, 0, 0x80, 0, 0]) in sent  # fastscan: who is there?
    assert bytes([0x11, 42, 0, 0, 0, 0, 0, 0]) in sent
    assert bytes([0x13, 0, 3, 0, 0, 0, 0, 0]) in sent
    assert bytes([0x15, 100, 0, 0, 0, 0, 0, 0]) in sent
    assert bytes([0x17, 0, 0, 0, 0, 0, 0, 0]) in sent
    assert bytes([0x04, 0, 0, 0, 0, 0, 0, 0]) in sent
    assert bytes([0x43, *struct.pack("<I", IDENT[3]), 0, 0, 0]) in sent
    confirm = bytes([0x51, *struct.pack("<I", IDENT[3]), 0, 3, 0])  # serial, next: vendor
    assert confirm in sent
