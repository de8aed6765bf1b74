"""The one name resolver (issue 41): every form people write an object in, and "did you
mean" when nothing matches."""

from __future__ import annotations

import pytest

from cobus.od import NameLookupError, ObjectDictionary, parse_address, resolve, resolve_object
from cobus.od import Variable as OdVariable
from tests.test_master_support import io_od


@pytest.fixture(scope="module")
def od() -> ObjectDictionary:
    return io_od()


def where(var: OdVariable) -> tuple[int, int]:
    return var.index, var.subindex


@pytest.mark.parametrize(
    ("key", "subindex", "expected"),
    [
        (0x1017, None, (0x1017, 0)),
        (0x1018, 1, (0x1018, 1)),
        ((0x1018, 1), None, (0x1018, 1)),
        ((0x1018, "Vendor-ID"), None, (0x1018, 1)),
        ("0x1018:01", None, (0x1018, 1)),
        ("0x1018:0A", None, None),  # (no sub-index 10: an error, below)
        ("1018h sub 2", None, (0x1018, 2)),
        ("1018sub3", None, (0x1018, 3)),
        ("0x1017", None, (0x1017, 0)),
        ("1017h", None, (0x1017, 0)),
        ("Producer heartbeat time", None, (0x1017, 0)),
        ("producer_heartbeat-TIME", None, (0x1017, 0)),
        ("  Producer   heartbeat time ", None, (0x1017, 0)),
        ("Identity object", "Vendor-ID", (0x1018, 1)),
        ("Identity object", "vendor id", (0x1018, 1)),
        ("Identity object", 4, (0x1018, 4)),
        ("Identity object", "2", (0x1018, 2)),
        ("Identity object.Vendor-ID", None, (0x1018, 1)),
        ("identity_object.product code", None, (0x1018, 2)),
        ("Identity object[3]", None, (0x1018, 3)),
        ("Identity object[0x4]", None, (0x1018, 4)),
        ("Vendor-ID", None, (0x1018, 1)),  # a sub-object by its own name, the only one
        ("Identity object", None, (0x1018, 0)),
        ("Setpoint", 0, (0x2001, 0)),
        ("Setpoint", "Setpoint", (0x2001, 0)),
        ("COB-ID SYNC", None, (0x1005, 0)),
        ("cob id sync", None, (0x1005, 0)),
    ],
)
def test_every_form_people_write(
    od: ObjectDictionary, key: object, subindex: object, expected: tuple[int, int] | None
) -> None:
    if expected is None:
        with pytest.raises(NameLookupError, match="has no sub-index 10"):
            resolve(od, key, subindex)  # type: ignore[arg-type]
        return
    assert where(resolve(od, key, subindex)) == expected  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("key", "subindex", "message"),
    [
        ("Producr heartbeat", None, r"no object named 'Producr heartbeat' \(did you mean "),
        (0x5000, None, "no object 0x5000"),
        ("0x5000:01", None, "no object 0x5000"),
        ("Identity object", "Vendor", r"has no sub-object .Vendor. \(did you mean .Vendor-ID.\?\)"),
        ("Identity object", 9, r"has no sub-index 9 \(it has 0, 1, 2, 3, 4\)"),
        ("Setpoint", 1, "is a single variable; it has no sub-index 1"),
        ("Transmission type", None, "no object named 'Transmission type'"),  # 8 of them
        ("Nothing such", None, "no object named 'Nothing such'$"),
        (3.5, None, "is no object name or index"),
        ("Identity object", 2.0, "is no sub-index"),
        ((1, 2, 3), None, "give \\(index, sub-index\\) once"),
    ],
)
def test_what_matches_nothing_says_why(
    od: ObjectDictionary, key: object, subindex: object, message: str
) -> None:
    with pytest.raises(NameLookupError, match=message) as caught:
        resolve(od, key, subindex)  # type: ignore[arg-type]
    assert isinstance(caught.value, KeyError)  # (as a dictionary miss is)


def test_suggestions_are_kept_on_the_error_and_can_be_left_out(od: ObjectDictionary) -> None:
    with pytest.raises(NameLookupError) as caught:
        resolve(od, "Producr heartbeat time")
    assert caught.value.suggestions[0] == "Producer heartbeat time"
    with pytest.raises(NameLookupError) as quiet:
        resolve(od, "Producr heartbeat time", suggest=False)
    assert quiet.value.suggestions == [] and "did you mean" not in str(quiet.value)
    with pytest.raises(NameLookupError) as record:
        resolve(od, "Identity objekt.Vendor-ID")
    assert "'Identity object.Vendor-ID'" in str(record.value)


def test_a_name_two_objects_share_says_which() -> None:
    od = io_od()
    first = od[0x2000]
    assert isinstance(first, OdVariable)
    twin = OdVariable(0x2005, 0, "counter", first.data_type)
    od.add(twin)
    with pytest.raises(
        NameLookupError, match=r"names several objects \(0x2000, 0x2005\)"
    ) as caught:
        resolve(od, "COUNTER")
    assert [o.index for o in caught.value.candidates] == [0x2000, 0x2005]
    assert where(resolve(od, "Counter")) == (0x2000, 0)  # the exact name is the one meant


def test_the_tables_follow_a_dictionary_that_grows() -> None:
    od = io_od()
    with pytest.raises(NameLookupError):
        resolve(od, "speed limit")
    od.add(OdVariable(0x2100, 0, "Speed limit", od[0x2000].data_type))  # type: ignore[union-attr]
    assert where(resolve(od, "speed limit")) == (0x2100, 0)


def test_objects_and_addresses(od: ObjectDictionary) -> None:
    assert resolve_object(od, "identity OBJECT").index == 0x1018
    assert resolve_object(od, "0x1018").index == 0x1018
    assert parse_address("0x6041:00") == (0x6041, 0)
    assert parse_address("6041h") == (0x6041, None)
    assert parse_address("6041") is None  # a bare number may be a name
    assert parse_address("Setpoint") is None
    with pytest.raises(NameLookupError):
        resolve_object(od, "DUMMY0005")  # the data type definitions are no names to use
    assert resolve_object(od, 5).index == 5


# ------------------------------------------------------------------ the resolver's users


def test_the_device_takes_every_form() -> None:
    from cobus.device import EntryNotFoundError, add_device
    from cobus.runtime import Network

    with Network(simulated=True) as net:
        device = add_device(net, 5, io_od())
        assert device.get("producer heartbeat time") == device.get(0x1017)
        assert device.get("Identity object.Vendor-ID") == device.get(0x1018, 1)
        assert device.get("0x1018:02") == device.get("Identity object", "product code")
        device.set("SETPOINT", 0, 12)
        assert device.get(0x2001) == 12
        with pytest.raises(EntryNotFoundError, match="did you mean 'Setpoint'") as unknown:
            device.get("Setpont")
        assert unknown.value.code == 0x06020000
        with pytest.raises(EntryNotFoundError, match="has no sub-index 9") as sub:
            device.get(0x1018, 9)
        assert sub.value.code == 0x06090011


def test_the_sdo_api_takes_every_form() -> None:
    from cobus.device import add_device
    from cobus.runtime import Network

    with Network(simulated=True) as net:
        add_device(net, 5, io_od())
        sdo = net.add_remote(5, io_od()).sdo
        vendor = sdo.read(0x1018, 1)
        assert sdo["0x1018:01"].read() == vendor
        assert sdo["1018h sub 1"].read() == vendor
        assert sdo["Identity object[1]"].read() == vendor
        assert sdo["vendor id"].read() == vendor
        assert sdo.read("identity_object", "VENDOR-ID") == vendor
        assert sdo["0x1018"].name == "Identity object"  # (a record: its sub-objects by [sub])


def test_the_files_name_objects_through_it() -> None:
    from cobus.master.config import ObjectIndex

    od = io_od()
    index = ObjectIndex(od, "io.eds")
    for text in ("Identity object[1]", "1018h sub 1", "Vendor-ID", "identity object.vendor id"):
        assert where(index.resolve(text)) == (0x1018, 1), text
    with pytest.raises(ValueError, match=r"io\.eds has no object named 'Setpont' \(did you mean"):
        index.resolve("Setpont")
    with pytest.raises(ValueError, match=r"io\.eds has no object 0x5000:00"):
        index.resolve("0x5000")
    with pytest.raises(ValueError, match=r"io\.eds has no object 0x1018:09"):
        index.resolve("0x1018:09")
    with pytest.raises(ValueError, match=r"io\.eds: 0x1018 .* has no sub-object 'Vendor'"):
        index.resolve("Identity object.Vendor")
    assert index.canonical(od[0x1018][1]) == "identity_object.vendor_id"  # type: ignore[index]


# ------------------------------------------------------------------ what a review found


def _tricky() -> ObjectDictionary:
    from cobus.od import Array, DataType, Record

    od = io_od()
    out = Record(0x2005, "Out")
    for sub in range(3):
        out.add(OdVariable(0x2005, sub, f"Out {sub}", DataType.UNSIGNED8))
    od.add(out)
    od.add(OdVariable(0x2006, 0, "Out[1]", DataType.UNSIGNED8))  # a name that looks like a form
    od.add(OdVariable(0x2007, 0, "Each", DataType.UNSIGNED8))  # ... like an address (EACh)
    dup = Array(0x200C, "Dup")
    dup.add(OdVariable(0x200C, 0, "Count", DataType.UNSIGNED8))
    dup.add(OdVariable(0x200C, 1, "Value", DataType.UNSIGNED8))
    dup.add(OdVariable(0x200C, 2, "Value", DataType.UNSIGNED8))
    od.add(dup)
    return od


def test_the_exact_eds_name_wins_over_every_form() -> None:
    od = _tricky()
    assert where(resolve(od, "Out[1]")) == (0x2006, 0)
    assert where(resolve(od, "Out[2]")) == (0x2005, 2)
    assert where(resolve(od, "Each")) == (0x2007, 0)
    assert parse_address("Each") is None and parse_address("EACAh") == (0xEACA, None)


def test_a_name_two_sub_objects_share_is_an_error_that_says_so() -> None:
    od = _tricky()
    with pytest.raises(NameLookupError, match="'Value' names sub-indices 1, 2") as caught:
        resolve(od, "Dup.Value")
    assert len(caught.value.candidates) == 2
    assert where(resolve(od, "Dup", "01")) == (0x200C, 1)  # (a leading zero: still a number)
    assert where(resolve(od, "Dup[02]")) == (0x200C, 2)


def test_the_name_tables_follow_a_removed_and_replaced_object() -> None:
    od = io_od()
    assert where(resolve(od, "counter")) == (0x2000, 0)
    old = od.remove(0x2000)
    od.add(OdVariable(0x2000, 0, "Speed", old.data_type))  # type: ignore[union-attr]
    assert where(resolve(od, "speed")) == (0x2000, 0)
    with pytest.raises(NameLookupError):
        resolve(od, "counter")


def test_a_network_file_names_a_sub_object_not_a_record() -> None:
    from cobus.master.config import ObjectIndex

    index = ObjectIndex(_tricky(), "t.eds")
    with pytest.raises(ValueError, match=r"'Digital inputs' is an array in t\.eds: name one"):
        index.resolve("Digital inputs")
    with pytest.raises(ValueError, match=r"'Dup\.Value' names several objects in t\.eds"):
        index.resolve("Dup.Value")
    assert where(index.resolve("0x1018")) == (0x1018, 0)  # (an address: its sub-index 0)


def test_membership_takes_what_indexing_takes() -> None:
    from cobus.device import add_device
    from cobus.runtime import Network

    with Network(simulated=True) as net:
        add_device(net, 5, io_od())
        sdo = net.add_remote(5, io_od()).sdo
        for key in ("0x1018:01", "Identity object.Vendor-ID", (0x1018, 1), "vendor id"):
            assert key in sdo, key
        assert "Nothing such" not in sdo and (0x1018, 9) not in sdo
        assert "vendor id" in sdo["Identity object"] and 9 not in sdo["Identity object"]
