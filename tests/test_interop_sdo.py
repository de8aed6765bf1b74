"""Interoperability of the SDO machines with python-canopen as the peer, on python-can's
virtual bus in real time (python-canopen runs its own threads, so no simulated clock here)."""

import os

import canopen
import pytest

from cobus.proto.sdo import DictBackend, SdoAbortedError, SdoServer
from cobus.runtime import Network

pytestmark = pytest.mark.interop

NODE = 5
LONG = bytes(range(256)) * 8  # 2048 bytes: many block segments, several sub-blocks


def _channel(name: str) -> str:
    return f"interop-{name}-{os.getpid()}"


def _canopen_od() -> canopen.ObjectDictionary:
    od = canopen.ObjectDictionary()
    dtype = canopen.objectdictionary.datatypes
    for index, sub, data_type, default in (
        (0x1000, 0, dtype.UNSIGNED32, 0x00020192),
        (0x1017, 0, dtype.UNSIGNED16, 0),
        (0x2000, 0, dtype.VISIBLE_STRING, "cobus interop device name, long enough"),
        (0x2001, 0, dtype.DOMAIN, b""),
        (0x2002, 0, dtype.UNSIGNED8, 7),
    ):
        var = canopen.objectdictionary.ODVariable(f"v{index:X}", index, sub)
        var.data_type = data_type
        var.access_type = "ro" if index == 0x2002 else "rw"
        var.default = default  # type: ignore[assignment]
        od.add_object(var)
    return od


@pytest.fixture
def canopen_server():
    channel = _channel("srv")
    net = canopen.Network()
    net.connect(interface="virtual", channel=channel)
    node = canopen.LocalNode(NODE, _canopen_od())
    net.add_node(node)
    yield channel, node
    net.disconnect()


def test_cobus_client_against_canopen_server(canopen_server):
    channel, node = canopen_server
    with Network(interface="virtual", channel=channel) as net:
        remote = net.aio.add_remote(NODE)
        sdo = remote.sdo
        # expedited upload and download
        assert net.run(sdo.upload(0x1000, 0)) == (0x00020192).to_bytes(4, "little")
        net.run(sdo.download(0x1017, 0, (1000).to_bytes(2, "little")))
        assert node.sdo[0x1017].raw == 1000
        # segmented upload and download
        name = net.run(sdo.upload(0x2000, 0))
        assert name == b"cobus interop device name, long enough"
        net.run(sdo.download(0x2001, 0, LONG[:300]))
        assert node.sdo[0x2001].raw == LONG[:300]
        # a block request to a server without block support falls back to segmented
        assert net.run(sdo.upload(0x2000, 0, block=True)) == name
        # aborts come back as typed errors with the code
        with pytest.raises(SdoAbortedError) as err:
            net.run(sdo.upload(0x3000, 0))
        assert err.value.code == 0x06020000
        with pytest.raises(SdoAbortedError) as err:
            net.run(sdo.download(0x2002, 0, b"\x01"))
        assert err.value.code == 0x06010002


@pytest.fixture
def cobus_server():
    channel = _channel("cli")
    backend = DictBackend(
        {
            (0x1000, 0): (0x00020192).to_bytes(4, "little"),
            (0x1008, 0): b"cobus device",
            (0x2001, 0): LONG,
            (0x2002, 0): b"",
        }
    )
    with Network(interface="virtual", channel=channel) as net:
        server = SdoServer(0x600 + NODE, 0x580 + NODE, backend)
        net.run(_attach(net, server))
        yield channel, backend


async def _attach(net, server):
    net.aio.attach(server, [0x600 + NODE])


@pytest.fixture
def canopen_client(cobus_server):
    channel, backend = cobus_server
    net = canopen.Network()
    net.connect(interface="virtual", channel=channel)
    node = canopen.RemoteNode(NODE, canopen.ObjectDictionary())
    net.add_node(node)
    node.sdo.RESPONSE_TIMEOUT = 2.0
    yield node, backend
    net.disconnect()


def test_canopen_client_expedited_and_segmented(canopen_client):
    node, backend = canopen_client
    assert node.sdo.upload(0x1000, 0) == (0x00020192).to_bytes(4, "little")
    assert node.sdo.upload(0x1008, 0) == b"cobus device"
    node.sdo.download(0x2002, 0, b"\x11\x22")
    assert backend.upload(0x2002, 0) == b"\x11\x22"
    node.sdo.download(0x2002, 0, LONG[:100])
    assert backend.upload(0x2002, 0) == LONG[:100]
    assert node.sdo.upload(0x2001, 0) == LONG


def test_canopen_client_block_upload_and_download_with_crc(canopen_client):
    node, backend = canopen_client
    with node.sdo.open(0x2001, 0, "rb", block_transfer=True) as f:
        assert f.read() == LONG
    with node.sdo.open(0x2002, 0, "wb", size=len(LONG), block_transfer=True) as f:
        f.write(LONG[::-1])
    assert backend.upload(0x2002, 0) == LONG[::-1]


def test_canopen_client_sees_our_aborts(canopen_client):
    node, _ = canopen_client
    with pytest.raises(canopen.SdoAbortedError) as err:
        node.sdo.upload(0x4000, 0)
    assert err.value.code == 0x06020000
