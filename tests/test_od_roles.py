"""Which objects are commands or process data rather than parameters (``cobus.od._roles``)."""

from __future__ import annotations

from cobus.od import (
    Access,
    CommandObjects,
    DataType,
    ObjectDictionary,
    Record,
    Variable,
    process_data_of,
)


def _device(device_type: int, *variables: Variable) -> ObjectDictionary:
    od = ObjectDictionary()
    od.add(Variable(0x1000, 0, "Device type", DataType.UNSIGNED32, Access.RO, default=device_type))
    for var in variables:
        od.add(var)
    return od


def test_without_a_dictionary_the_cia_401_and_402_commands_are_known() -> None:
    commands = CommandObjects()
    assert commands.reason(0x6040, 0) is not None
    assert commands.reason(0x6840, 0) == (
        "the CiA 402 controlword: it switches the drive on, off and into motion (axis 2)"
    )
    assert commands.reason(0x60FF, 0) == "a CiA 402 set-point (target velocity)"
    assert commands.reason(0x60FE, 1) is not None  # physical outputs
    assert commands.reason(0x60FE, 2) is None  # their bit mask: configuration
    assert commands.reason(0x6200, 1) == "a CiA 401 output (write outputs 8-bit)"
    assert commands.reason(0x6411, 3) is not None
    assert commands.reason(0x1011, 1) is not None
    assert commands.reason(0x6065, 0) is None  # following error window
    assert commands.reason(0x6081, 0) is None  # profile velocity
    assert commands.reason(0x2000, 0) is None


def test_the_device_type_picks_the_profile_table() -> None:
    drive = CommandObjects(
        _device(0x00020192, Variable(0x6200, 0, "a drive's own 6200h", DataType.UNSIGNED8))
    )  # 402: its own 6200h is no CiA 401 output
    assert drive.reason(0x6040, 0) is not None and drive.reason(0x6200, 0) is None
    io = CommandObjects(
        _device(0x000F0191, Variable(0x6040, 0, "Some 401 object", DataType.UNSIGNED16))
    )  # 401: its own 6040h is no CiA 402 controlword
    assert io.reason(0x6200, 1) is not None and io.reason(0x6040, 0) is None
    encoder = CommandObjects(
        _device(
            0x00010196,  # 406: neither table applies to its own objects
            Variable(0x6040, 0, "Operating parameters", DataType.UNSIGNED16),
        )
    )
    assert encoder.reason(0x6040, 0) is None
    # an object its dictionary lacks is judged by every table: a set for another device
    assert encoder.reason(0x6200, 1) is not None and io.reason(0x6060, 0) is not None
    assert encoder.reason(0x1010, 1) is not None  # the save command is one everywhere


def test_what_the_rpdo_mapping_receives_is_process_data() -> None:
    mapping = Record(0x1600, "RPDO1 mapping")
    mapping.add(Variable(0x1600, 0, "count", DataType.UNSIGNED8, default=2))
    mapping.add(Variable(0x1600, 1, "entry 1", DataType.UNSIGNED32, default=0x20010010))
    mapping.add(Variable(0x1600, 2, "entry 2", DataType.UNSIGNED32, default=0x00050008))  # dummy
    mapping.add(Variable(0x1600, 3, "entry 3", DataType.UNSIGNED32, default=0x20020010))  # off
    od = _device(0, Variable(0x2001, 0, "speed", DataType.UNSIGNED16, Access.RW, True))
    od.add(mapping)
    commands = CommandObjects(od)
    assert commands.reason(0x2001, 0) == (
        "process data the device receives: the EDS maps it to RPDO 1"
    )
    assert commands.reason(0x2002, 0) is None  # beyond the count
    assert commands.reason(0x0005, 0) is None


def test_rww_and_write_only_objects_are_process_data_but_no_commands() -> None:
    rww = Variable(0x6081, 0, "Profile velocity", DataType.UNSIGNED32, Access.RWW, True)
    wo = Variable(0x2100, 0, "trigger", DataType.UNSIGNED8, Access.WO)
    rw = Variable(0x6065, 0, "Following error window", DataType.UNSIGNED32, Access.RW)
    commands = CommandObjects(_device(0x00020192, rww, wo, rw))
    assert commands.reason(0x6081, 0) is None
    assert process_data_of(rww, commands) == (
        "process data: the EDS marks it rww (written by an RPDO)"
    )
    assert process_data_of(wo, commands) is not None
    assert process_data_of(rw, commands) is None


def test_a_dialect_table_replaces_the_cia_tables() -> None:
    commands = CommandObjects(table={0x2024: "p_ven, the target velocity"})
    assert commands.reason(0x2024, 0) == "p_ven, the target velocity"
    assert commands.reason(0x6040, 0) is None and commands.reason(0x1010, 1) is None
