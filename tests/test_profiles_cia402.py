"""CiA 402 sans I/O: the statusword decoding, the command paths, the error texts."""

from __future__ import annotations

import pytest

from cobus.profiles import Command, OperationMode, PowerState, Statusword, error_text
from cobus.profiles.cia402 import command_towards

P = PowerState

#: The CiA 402 statusword of each state (bits 0-3, 5, 6), and the same with every bit the
#: decoding must ignore set (voltage enabled, warning, remote, target reached, 12-15).
STATES = {
    P.NOT_READY_TO_SWITCH_ON: 0x00,
    P.SWITCH_ON_DISABLED: 0x40,
    P.READY_TO_SWITCH_ON: 0x21,
    P.SWITCHED_ON: 0x23,
    P.OPERATION_ENABLED: 0x27,
    P.QUICK_STOP_ACTIVE: 0x07,
    P.FAULT_REACTION_ACTIVE: 0x0F,
    P.FAULT: 0x08,
}
IGNORED = 0x10 | 0x80 | 0x200 | 0x400 | 0x800 | 0xF000


@pytest.mark.parametrize("state", list(STATES))
def test_every_state_decodes_from_its_bits_whatever_the_other_bits(state: PowerState) -> None:
    assert P.from_statusword(STATES[state]) is state
    assert P.from_statusword(STATES[state] | IGNORED) is state
    # bit 5 (quick stop) is part of the state only where CiA 402 says so
    if state in (P.NOT_READY_TO_SWITCH_ON, P.SWITCH_ON_DISABLED, P.FAULT):
        assert P.from_statusword(STATES[state] | 0x20) is state


def _model(state: PowerState, command: Command) -> PowerState:
    """The device side of CiA 402's transitions, for the commands ``command_towards`` gives
    (quick stop option 2: quick stop active ends in switch on disabled)."""
    if command is Command.FAULT_RESET:
        return P.SWITCH_ON_DISABLED if state is P.FAULT else state
    if command is Command.DISABLE_VOLTAGE:
        return P.SWITCH_ON_DISABLED
    if command is Command.SHUTDOWN:
        return P.READY_TO_SWITCH_ON if state is not P.QUICK_STOP_ACTIVE else state
    if command is Command.SWITCH_ON:  # also disable operation (the same bits)
        if state in (P.READY_TO_SWITCH_ON, P.OPERATION_ENABLED):
            return P.SWITCHED_ON
        return state
    if command is Command.ENABLE_OPERATION:
        return P.OPERATION_ENABLED if state is P.SWITCHED_ON else state
    raise AssertionError(command)


@pytest.mark.parametrize(
    "target",
    [P.OPERATION_ENABLED, P.SWITCHED_ON, P.READY_TO_SWITCH_ON, P.SWITCH_ON_DISABLED],
)
def test_the_commands_lead_from_every_state_to_every_target(target: PowerState) -> None:
    for start in STATES:
        state, steps = start, 0
        while state is not target:
            command = command_towards(state, target)
            if command is None:  # only the drive leaves these
                assert state in (P.NOT_READY_TO_SWITCH_ON, P.FAULT_REACTION_ACTIVE)
                break
            state = _model(state, command)
            steps += 1
            assert steps <= 4, f"{start} -> {target} does not end"
    assert command_towards(target, target) is None


def test_a_target_no_command_leads_to_is_refused_with_the_possible_ones() -> None:
    with pytest.raises(ValueError, match=r"FAULT is not a state .* OPERATION_ENABLED"):
        command_towards(P.SWITCHED_ON, P.FAULT)


def test_statusword_prints_state_and_the_mode_s_own_bits() -> None:
    sw = Statusword(0x1637, OperationMode.PROFILE_POSITION)
    assert sw.state is P.OPERATION_ENABLED and sw.target_reached and sw.voltage_enabled
    assert str(sw) == (
        "0x1637 OPERATION_ENABLED (voltage enabled, remote, target reached, set-point acknowledge)"
    )
    assert "homing attained" in str(Statusword(0x1637, OperationMode.HOMING))
    assert str(Statusword(0x0008)) == "0x0008 FAULT"
    assert OperationMode.CYCLIC_SYNC_POSITION.supported_bit == 0x80
    assert str(OperationMode.HOMING) == "HOMING" and str(P.FAULT) == "FAULT"


def test_error_codes_have_the_cia402_text_or_their_class() -> None:
    assert error_text(0x8611) == "Following error"
    assert error_text(0x2310) == "Continuous over-current"
    assert error_text(0x4321) == "Temperature (4321h)"  # no CiA 402 text: the CiA 301 class


def test_each_state_s_statusword_bits_decode_back_to_it() -> None:
    """One encoding of the power states: what the simulated drive sends is what the master
    side decodes (with or without bit 4, voltage enabled, and the mode bits above)."""
    from cobus.profiles.cia402 import STATE_BITS
    from cobus.sim import drive402 as simulated

    assert set(STATE_BITS) == set(PowerState)
    assert simulated._STATE_BITS is STATE_BITS
    for state, bits in STATE_BITS.items():
        for extra in (0x0000, 0x0010, 0x0200, 0xFC10):
            assert PowerState.from_statusword(bits | extra) is state, (state, hex(extra))


# ------------------------------------------------------------------ the numbered transitions


def test_the_transitions_are_numbered_as_the_standard_numbers_them() -> None:
    from cobus.profiles.cia402 import TRANSITIONS, Command, PowerState, transition

    assert [t.number for t in TRANSITIONS] == list(range(17))
    P = PowerState
    assert transition(P.SWITCH_ON_DISABLED, Command.SHUTDOWN).number == 2  # type: ignore[union-attr]
    assert transition(P.OPERATION_ENABLED, Command.DISABLE_OPERATION).number == 5  # type: ignore[union-attr]
    assert transition(P.OPERATION_ENABLED, Command.SHUTDOWN).number == 8  # type: ignore[union-attr]
    assert transition(P.QUICK_STOP_ACTIVE, Command.ENABLE_OPERATION).number == 16  # type: ignore[union-attr]
    assert transition(P.FAULT, Command.FAULT_RESET).number == 15  # type: ignore[union-attr]
    assert transition(P.SWITCH_ON_DISABLED, Command.QUICK_STOP) is None
    assert transition(P.FAULT_REACTION_ACTIVE, Command.SHUTDOWN) is None


@pytest.mark.parametrize(
    ("controlword", "command"),
    [
        (0x00, "DISABLE_VOLTAGE"),
        (0x0D, "DISABLE_VOLTAGE"),
        (0x02, "QUICK_STOP"),
        (0x0B, "QUICK_STOP"),
        (0x06, "SHUTDOWN"),
        (0x0E, "SHUTDOWN"),
        (0x07, "SWITCH_ON"),
        (0x0F, "ENABLE_OPERATION"),
        (0x1F, "ENABLE_OPERATION"),  # (bit 4 is the mode's)
        (0x80, "FAULT_RESET"),
        (0x8F, "FAULT_RESET"),
    ],
)
def test_a_controlword_gives_one_command(controlword: int, command: str) -> None:
    from cobus.profiles.cia402 import Command, command_of

    assert command_of(controlword) is Command[command]


def test_every_step_of_the_path_table_is_a_numbered_transition() -> None:
    from cobus.profiles.cia402 import PowerState, command_towards, transition

    targets = (
        PowerState.OPERATION_ENABLED,
        PowerState.SWITCHED_ON,
        PowerState.READY_TO_SWITCH_ON,
        PowerState.SWITCH_ON_DISABLED,
    )
    for target in targets:
        for current in PowerState:
            command = command_towards(current, target)
            if command is not None:
                assert transition(current, command) is not None, (current, target, command)
