"""EC motor with its own CAN profile "based on CANopen" (seed 002), address 1-15.

The motor speaks a dialect of its own (:mod:`cobus.sim._ecproto`): expedited SDO only, read
replies with command byte 40h and a shortened DLC, no abort (a refused request is reported by
the emergency ``080+a [8] 10 00 m_sss c_sss m_ssm``), a status poll by an empty RPDO1, and NMT
reset only: no boot-up, heartbeat, guarding, SYNC or TIME.

Objects (sub-index 0 = 16-bit access, 1 = 32-bit access; on the bit-field objects
2000h-200Fh sub 2 SETs, 3 CLeaRs and 4 NEGates the bits of a mask):

- user memory URAM 2000h-2008h and 2030h-203Bh (32 bits each);
- bit fields 200Ah m_eci (I/O), 200Bh S_err (SW protection mask), 200Ch c_sss (communication
  status), 200Dh m_set (motor control), 200Eh m_sss (latched errors), 200Fh m_ssm (status,
  mode in bits 4-0);
- read-only values 2010h p_pox, 2011h p_vex, 2012h h_poz, 2013h h_tet, 2014h h_vel,
  2015h iq_ref, 2016h udc, 2017h tsn, 2018h tcu, 2019h p_err;
- settings 2020h u_tim, 2021h/2022h P_lil/P_lih, 2023h p_pon, 2024h p_ven, 2025h/2026h
  p_acc/p_dec, 2027h p_mon, 202Fh c_set;
- functions 2040h (debug read at a physical address), 2041h SW version (00BEh = ECA19.0),
  2042h set mode (T_MOD), 2043h/2044h user program 1/2 (0 stops, else the start address),
  2045h sub 0 clear errors, 1 zero position (stopped), 2 zero position running (mode 5 only),
  3/4 zero to the absolute position +/-.

Units (physical = raw x factor, :data:`UNITS`): V velocity 0.1875 rpm, A/D acceleration
0.0146484375 rpm/ms, P position 0.1171875 deg, M torque 0.000135 Nm, C current 0.000135 A,
voltage 0.01 V, T temperature 0.01 degC, K time 0.8 ms.

Modes (T_MOD): 0 MON, 1 OFF, 2 STP (emergency stop, then 3 by itself once stopped), 3 PON
(holding), 4 MOM (torque), 5 VEL (velocity), 6 POZ (position), 15 VELP (velocity from the
potentiometer), 29 ERR (entered on a protection trip), 31 RES (hardware reset). Mode 1 leaves
29 once the cause is gone; the power stage is not switched on while the motor turns.

Assumptions where the document is silent or ambiguous (documented, tested): c_set holds
adr0 in bits 0-3, the CAN bit-rate code in bits 4-6, the RS232 rate in bit 7, the group
address adr1 in bits 8-11 and the monitor mask in bits 12-15 (the printed bit layout is
garbled); a CAN write of c_set reaches the motor's RAM only, the RS232 set-up tool saves it
(not on this bus), so a reset brings back the configured address; customer modes 16-20 and the
internal modes 28-30 are refused (no customer data structures, no monitor); the protection
limits are :data:`LIMITS`; the SW protection trips on the m_sss bits selected by S_err
(default :data:`DEFAULT_S_ERR`), the HW protection always; ``ber`` follows bhw/bsw/brs/bid
and mode 29, ``bwa`` any other latched bit; u_tim counts K units (0.8 ms); 2040h reads the
two addresses the document names (0367h p_ven, 0365h p_pon) and 0 elsewhere; the group
address, the ECI200 module (m_set bits 8-11) and cbi are held but not simulated; user
programs set ``bup`` but are not interpreted.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, ClassVar

from cobus.profiles.ecmotor import MODES, UNITS
from cobus.proto import Event, Frame
from cobus.proto.connection_set import ERROR_CONTROL_BASE
from cobus.proto.sdo import SdoAbortCode
from cobus.runtime.network import AsyncNetwork, MachineHost, Subscription
from cobus.sim._ecproto import (
    EcDialect,
    EcRefusal,
    FrameRejected,
    RequestRefused,
    ResetRequested,
    StatusRequested,
    emcy_frame,
    status_frame,
)
from cobus.sim.base import SimulatedDevice, SimulationError

__all__ = ["DEFAULT_S_ERR", "LIMITS", "MODES", "UNITS", "EcMotor"]

MON, OFF, STP, PON, MOM, VEL, POZ, VELP, ERR, RES = 0, 1, 2, 3, 4, 5, 6, 15, 29, 31
_POWER_ON_MODES = frozenset((STP, PON, MOM, VEL, POZ, VELP))

# m_sss (200Eh): latched errors and warnings
BID, BRS, BHW, BSW, BUH, BUL, BIH, BEP = (1 << n for n in (15, 14, 13, 12, 11, 10, 9, 8))
BTS, BTM, BTB, BEK, BEN, BEE, BLL, BLH = (1 << n for n in (7, 6, 5, 4, 3, 2, 1, 0))
_ERRORS = BID | BRS | BHW | BSW
#: The causes the SW protection may trip on (selected by S_err).
_SW_CAUSES = BUH | BUL | BIH | BEP | BTS | BTM | BTB | BEE
#: S_err after power-on: every SW protection cause.
DEFAULT_S_ERR = _SW_CAUSES
# m_ssm (200Fh)
BER, BWA, BX, BIO, BPZ, BRU, BPO, BUP = (1 << n for n in (15, 14, 13, 12, 11, 10, 9, 8))
BCI, BCO, BEX = 1 << 7, 1 << 6, 1 << 5
# c_sss (200Ch)
BCER, BCEF, BCSE, BCSS, BCOK, BCEP = 1 << 15, 1 << 14, 1 << 9, 1 << 8, 1 << 5, 1 << 4
# m_set (200Dh)
CAR, CBI, CDI, CEN, CLP, CDN = 1 << 14, 1 << 13, 1 << 12, 1 << 3, 1 << 1, 1 << 0

#: Bits a master may change by SET/CLR/NEG (or a 16-bit write) in each bit-field object;
#: the other bits are the motor's.
_MASTER_BITS: Mapping[int, int] = {
    0x200A: 0x807F,  # outputs ou0-ou2, io3-io6, the read-function bit
    0x200B: 0xFFFF,
    0x200C: BCER | BCEF | BCSE | BCSS | BCOK | BCEP,
    0x200D: 0xFFFF,
    0x200E: 0xFFFF,  # bits cleared stay cleared until their cause returns
    0x200F: BX | BCI | BCO | BEX,
}

#: Protection limits (raw units): supply (0.01 V), sensor temperature (0.01 degC), thermal
#: utilisation (0.01 %), position error (P).
LIMITS: Mapping[str, int] = {
    "udc_max": 6000,
    "udc_min": 1800,
    "tsn_max": 8500,
    "tcu_max": 10000,
    "p_err_max": 3072,
}

SW_VERSION = 0x00BE  # ECA19.0
_URAM = (*range(0x2000, 0x2009), *range(0x2030, 0x203C))
# read-only values: index -> (size in bytes, signed)
_VALUES: Mapping[int, tuple[int, bool]] = {
    0x2010: (4, True),
    0x2011: (2, True),
    0x2012: (4, True),
    0x2013: (4, True),
    0x2014: (2, True),
    0x2015: (2, True),
    0x2016: (2, False),
    0x2017: (2, False),
    0x2018: (2, False),
    0x2019: (2, True),
}
# settings: index -> (size, signed, default)
_SETTINGS: Mapping[int, tuple[int, bool, int]] = {
    0x2020: (4, False, 0),
    0x2021: (4, True, -(1 << 30)),
    0x2022: (4, True, 1 << 30),
    0x2023: (4, True, 0),
    0x2024: (2, True, 0),
    0x2025: (2, False, 200),
    0x2026: (2, False, 200),
    0x2027: (2, True, 16384),
    0x202F: (2, False, 0),
}
_DEBUG_ADDRESSES = {0x0367: 0x2024, 0x0365: 0x2023}  # the document's example addresses

_V_TO_P = 0.1875 * 360 / 60 / 0.1171875  # P units per second per V unit (= 9.6)
_A_TO_V = 0.0146484375 / 0.1875 * 1000  # V units per second per A unit (= 78.125)
_P_PER_TURN = 3072  # 360 deg / 0.1171875
_RATED_TORQUE = 8000  # M units: the torque the thermal model takes as 100 %
_THERMAL_TIME = 60.0  # s
_COAST = 20000.0  # V units per second the rotor loses without the power stage
_MOMENT = 20.0  # V units per second per M unit of torque surplus in torque mode
_STOP = 4096 * _A_TO_V  # emergency stop deceleration


def _signed(value: int, size: int) -> int:
    bits = size * 8
    value &= (1 << bits) - 1
    return value - (1 << bits) if value >> (bits - 1) else value


def _clamp(value: float, size: int, signed: bool) -> int:
    bits = size * 8
    low, high = (-(1 << bits - 1), (1 << bits - 1) - 1) if signed else (0, (1 << bits) - 1)
    return int(max(low, min(high, round(value))))


class EcMotor(SimulatedDevice):
    """An EC motor at address ``node_id`` (1-15) on ``network``.

    Options: ``quirks`` (:attr:`QUIRKS`), ``tick`` (s between model steps), ``can_rate`` (the
    bit-rate code in c_set, 0-7), ``group`` (adr1, 0-15), ``sw_version`` (2041h).
    """

    kind: ClassVar[str] = "ec_motor"
    QUIRKS: ClassVar[Mapping[str, str]] = {
        "read_reply_40": "answers a read with command byte 40h (CiA: 4Bh/43h by size)",
        "short_replies": "cuts replies to their data (DLC 4 for writes, 6/8 for reads; CiA: 8)",
        "no_abort": "answers a refused request with no SDO abort, only its emergency",
        "short_requests": "accepts requests of 4..8 bytes (CiA: 8)",
        "emcy_code_as_printed": "sends the emergency code bytes as printed, 10 00 (CiA 1000h "
        "generic error is 00 10)",
        "no_bootup": "sends no boot-up message after power-on or reset",
    }
    FAULTS: ClassVar[Mapping[str, str]] = {
        "overload": "a load torque= (Nm, default twice the torque limit) on the shaft; 0 "
        "removes it: above the torque limit the current saturates (bih), the motor heats "
        "(btm) and stalls (bep)",
        "overtemperature": "the sensor temperature celsius= (degC, default 90): bts above "
        f"{LIMITS['tsn_max'] / 100:g} degC",
        "supply": "the DC link voltage volts= (V): bul below "
        f"{LIMITS['udc_min'] / 100:g} V, buh above {LIMITS['udc_max'] / 100:g} V",
        "hw_protection": "the hardware protection trips (bhw) while active=True",
        "bio": "the BIO input level= (True/False); with m_set.cen, 0 switches the power stage "
        "off (ben)",
    }
    #: The parameters each fault takes (kind, "?" when optional): checked when a rig loads.
    FAULT_PARAMS: ClassVar[Mapping[str, Mapping[str, str]]] = {
        "overload": {"torque": "number?"},
        "overtemperature": {"celsius": "number?"},
        "supply": {"volts": "number"},
        "hw_protection": {"active": "bool?"},
        "bio": {"level": "bool?"},
    }

    def __init__(
        self,
        network: AsyncNetwork,
        node_id: int,
        *,
        quirks: Mapping[str, bool] | None = None,
        name: str | None = None,
        tick: float = 0.01,
        can_rate: int = 5,
        group: int = 0,
        sw_version: int = SW_VERSION,
    ) -> None:
        if not isinstance(node_id, int) or not 1 <= node_id <= 15:
            raise SimulationError(
                f"EC motor address {node_id!r} is out of range: c_set.adr0 holds 1..15"
            )
        super().__init__(network, node_id, quirks=quirks, name=name)
        if not isinstance(tick, int | float) or not tick > 0:
            raise SimulationError(f"tick={tick!r} must be a positive number of seconds")
        if not isinstance(can_rate, int) or not 0 <= can_rate <= 7:
            raise SimulationError(f"can_rate={can_rate!r}: the CAN bit-rate code is 0..7")
        if not isinstance(group, int) or not 0 <= group <= 15:
            raise SimulationError(f"group={group!r}: the group address adr1 is 0..15")
        self.tick = float(tick)
        self.sw_version = sw_version & 0xFFFF
        #: c_set as saved in the motor's EEPROM (by its RS232 set-up tool)
        self.eeprom_c_set = node_id | can_rate << 4 | group << 8
        self._host: MachineHost | None = None
        self._subs: list[Subscription] = []
        # the world around the motor, kept while the power is off
        self.load = 0  # M units against the motor's torque
        self.udc = 4800
        self.tsn = 2500
        self.bio_input = True
        self.inputs = 0  # in7-in9 and io3-io6 as m_eci bits
        self.potentiometer = 0  # V units the potentiometer asks for in mode 15
        self.hw_fault = False
        self._reset_state()

    # ------------------------------------------------------------------ life cycle
    def start(self) -> None:
        if self.powered:
            return
        other = self.network.devices.get(self.node_id)
        if other is not None and other is not self:
            raise SimulationError(
                f"{self.name}: node-ID {self.node_id} is taken by {other!r} on this network; "
                "give each simulated device its own node-ID"
            )
        super().start()
        self.network.devices.claim(self.node_id, self)
        self._reset_state()
        q = self.quirks
        dialect = EcDialect(
            self.node_id,
            self,
            cia_replies=not q["read_reply_40"],
            cia_length=not q["short_replies"],
            cia_aborts=not q["no_abort"],
            cia_requests=not q["short_requests"],
        )
        self._host = self.network.attach(dialect, (), self._on_event)
        for cob_id in (0x000, dialect.status_cob_id, dialect.rx_cob_id):
            self._subs.append(self.network.subscribe(cob_id, self._on_frame))
        self._bootup()
        self.every(self.tick, self._step)

    def power_off(self) -> None:
        for sub in self._subs:
            sub.cancel()
        self._subs.clear()
        if self._host is not None:
            self._host.close()
            self._host = None
        self.network.devices.release(self.node_id, self)
        super().power_off()

    def _reset_state(self) -> None:
        """The motor's RAM after power-on or a hardware reset."""
        self.address = self.eeprom_c_set & 0x0F
        self.mode = OFF
        self.m_sss = BRS  # a reset occurred: the master initialises again
        self.c_sss = 0
        self.m_set = 0
        self.m_eci = 0
        self.s_err = DEFAULT_S_ERR
        self.m_ssm_user = 0  # the master's bits of m_ssm (bx, bci, bco, bex)
        self.uram: dict[int, int] = dict.fromkeys(_URAM, 0)
        self.settings: dict[int, int] = {i: d for i, (_, _, d) in _SETTINGS.items()}
        self.settings[0x202F] = self.eeprom_c_set
        self.programs = [0, 0]
        self.velocity = 0.0  # h_vel, V units
        self.command_velocity = 0.0  # p_vex
        self.position = 0.0  # h_poz, P units
        self.command_position = 0.0  # p_pox
        self.torque = 0.0  # iq_ref, M units
        self.tcu = 0.0
        self.time_units = 0.0  # u_tim, K units
        self.in_position = False

    def _bootup(self) -> None:
        if not self.quirks["no_bootup"]:
            self._send(Frame(ERROR_CONTROL_BASE + self.address, b"\x00"))

    def _send(self, frame: Frame) -> None:
        self.network.send(frame)

    def _on_frame(self, frame: Frame, now: float) -> None:
        if self._host is not None:
            self._host.feed(frame, now)

    def _on_event(self, event: Event) -> None:
        if isinstance(event, StatusRequested):
            self._send_status()
        elif isinstance(event, ResetRequested):
            self.hardware_reset()
        elif isinstance(event, RequestRefused):
            self.c_sss |= BCEF
            self._send_emcy()
        elif isinstance(event, FrameRejected):
            self.c_sss |= BCER
            self._send_emcy()

    def hardware_reset(self) -> None:
        """NMT reset or mode RES: the motor starts again from its EEPROM set-up."""
        for handle in self._timers.values():
            handle.cancel()
        self._timers.clear()
        for sub in self._subs:
            sub.cancel()
        self._subs.clear()
        if self._host is not None:
            self._host.close()
            self._host = None
        self.powered = False
        self.start()

    # ------------------------------------------------------------------ derived words
    @property
    def power_stage(self) -> bool:
        """Whether the power stage is on (bpz)."""
        if self.mode not in _POWER_ON_MODES:
            return False
        return not (self.m_set & CEN and not self.bio_input)

    @property
    def m_ssm(self) -> int:
        """The status word M_SSM as the motor reports it: mode, error and warning bits, inputs."""
        word = self.mode & 0x1F | self.m_ssm_user
        if self.m_sss & _ERRORS or self.mode == ERR:
            word |= BER
        if self.m_sss & ~_ERRORS:
            word |= BWA
        if self.bio_input:
            word |= BIO
        if self.power_stage:
            word |= BPZ
        if abs(self.velocity) >= 0.5:
            word |= BRU
        if self.in_position:
            word |= BPO
        if any(self.programs):
            word |= BUP
        return word

    @property
    def eci(self) -> int:
        """m_eci: the master's output bits and the input levels."""
        return self.m_eci & _MASTER_BITS[0x200A] | self.inputs & 0x0380

    def _value(self, index: int) -> tuple[int, int]:
        """The raw value and size of a readable object."""
        if index in _VALUES:
            size, signed = _VALUES[index]
            raw = {
                0x2010: self.command_position,
                0x2011: self.command_velocity,
                0x2012: self.position,
                0x2013: self.position % _P_PER_TURN,
                0x2014: self.velocity,
                0x2015: self.torque,
                0x2016: self.udc,
                0x2017: self.tsn,
                0x2018: self.tcu,
                0x2019: self.command_position - self.position,
            }[index]
            return _clamp(raw, size, signed), size
        if index in _SETTINGS:
            size = _SETTINGS[index][0]
            if index == 0x2020:
                return int(self.time_units) & 0xFFFFFFFF, 4
            return self.settings[index], size
        bits = {
            0x200A: self.eci,
            0x200B: self.s_err,
            0x200C: self.c_sss,
            0x200D: self.m_set,
            0x200E: self.m_sss,
            0x200F: self.m_ssm,
        }
        if index in bits:
            return bits[index], 2
        raise EcRefusal(SdoAbortCode.NO_OBJECT, f"0x{index:04X} is not used", unused_index=True)

    # ------------------------------------------------------------------ the SDO back end
    def read(self, index: int, subindex: int, request: bytes) -> tuple[int, int]:
        """Serve a read (the dialect's back end)."""
        if index == 0x2040:
            if subindex not in (0, 1):
                raise EcRefusal(SdoAbortCode.NO_SUBINDEX, "2040h: sub 0 reads U16, sub 1 U32")
            address = request[0] | request[1] << 8
            target = _DEBUG_ADDRESSES.get(address)
            value = self._value(target)[0] if target is not None else 0
            return (value & 0xFFFF, 2) if subindex == 0 else (value & 0xFFFFFFFF, 4)
        if index == 0x2041:
            self._sub(index, subindex, 0)
            return self.sw_version, 2
        if 0x2042 <= index <= 0x2045:
            raise EcRefusal(SdoAbortCode.READ_WRITE_ONLY, f"0x{index:04X} is a function: write it")
        if index in self.uram:
            word = self.uram[index]
            if subindex == 0:
                return word & 0xFFFF, 2
            self._sub(index, subindex, 1)
            return word, 4
        value, size = self._value(index)
        self._sub(index, subindex, 0 if size == 2 else 1)
        return value & (0xFFFF if size == 2 else 0xFFFFFFFF), size

    @staticmethod
    def _sub(index: int, subindex: int, expected: int) -> None:
        if subindex != expected:
            width = "16-bit (sub 0)" if expected == 0 else "32-bit (sub 1)"
            raise EcRefusal(
                SdoAbortCode.NO_SUBINDEX,
                f"0x{index:04X} takes {width} access, not sub-index {subindex}",
            )

    def write(self, index: int, subindex: int, data: bytes) -> None:
        """Serve a write (the dialect's back end)."""
        word = data[0] | data[1] << 8
        dword = int.from_bytes(data[:4], "little")
        bitwise = 0x2000 <= index <= 0x200F
        if bitwise and subindex in (2, 3, 4):
            self._bit_operation(index, subindex, word)
            return
        if index in self.uram:
            if subindex == 0:
                self.uram[index] = self.uram[index] & 0xFFFF0000 | word
            else:
                self._sub(index, subindex, 1)
                self.uram[index] = dword
            return
        if index in _MASTER_BITS:
            self._sub(index, subindex, 0)
            if index in (0x200C, 0x200E, 0x200F):
                raise EcRefusal(
                    SdoAbortCode.WRITE_READ_ONLY,
                    f"0x{index:04X} is read-only: change its bits by SET/CLR/NEG (sub 2/3/4)",
                )
            self._set_bits(index, word)
            return
        if index in _SETTINGS:
            size, signed, _ = _SETTINGS[index]
            self._sub(index, subindex, 0 if size == 2 else 1)
            raw = word if size == 2 else dword
            value = _signed(raw, size) if signed else raw
            if index == 0x2020:
                self.time_units = float(value)
            self.settings[index] = value
            if index in (0x2023, 0x2024):
                self.in_position = False
            return
        if index == 0x2042:
            self._sub(index, subindex, 0)
            self.set_mode(word)
            return
        if index in (0x2043, 0x2044):
            self._sub(index, subindex, 0)
            self.programs[index - 0x2043] = word
            return
        if index == 0x2045:
            self._zero(subindex)
            return
        if index in _VALUES or index == 0x2041 or index == 0x2040:
            raise EcRefusal(SdoAbortCode.WRITE_READ_ONLY, f"0x{index:04X} is read-only")
        raise EcRefusal(SdoAbortCode.NO_OBJECT, f"0x{index:04X} is not used", unused_index=True)

    def _bit_operation(self, index: int, subindex: int, mask: int) -> None:
        if index in self.uram:
            low = self.uram[index] & 0xFFFF
            new = {2: low | mask, 3: low & ~mask, 4: low ^ mask}[subindex]
            self.uram[index] = self.uram[index] & 0xFFFF0000 | new & 0xFFFF
            return
        if index not in _MASTER_BITS:
            raise EcRefusal(SdoAbortCode.NO_OBJECT, f"0x{index:04X} is not used", unused_index=True)
        current = self._value(index)[0]
        new = {2: current | mask, 3: current & ~mask, 4: current ^ mask}[subindex]
        self._set_bits(index, new & 0xFFFF)

    def _set_bits(self, index: int, new: int) -> None:
        allowed = _MASTER_BITS[index]
        if index == 0x200A:
            self.m_eci = new & allowed
        elif index == 0x200B:
            self.s_err = new
        elif index == 0x200C:
            self.c_sss = self.c_sss & ~allowed | new & allowed
            if self.c_sss & BCSS:  # a request: send the status, once
                self.c_sss &= ~BCSS
                self._send_status()
            if self.c_sss & BCSE:  # a request: send the emergency, once
                self.c_sss &= ~BCSE
                self._send_emcy()
        elif index == 0x200D:
            self.m_set = new
        elif index == 0x200E:
            self.m_sss = new
        else:
            self.m_ssm_user = new & allowed

    def _zero(self, subindex: int) -> None:
        turning = abs(self.velocity) >= 0.5
        if subindex == 0:  # clear errors and warnings: the causes still there come back
            self.m_sss = 0
            self.c_sss &= ~(BCER | BCEF | BCEP | BCOK)
        elif subindex == 1:
            if turning:
                raise EcRefusal(SdoAbortCode.DEVICE_STATE, "2045h sub 1: the motor turns")
            self._shift_position(-self.position)
        elif subindex == 2:
            if self.mode != VEL:
                raise EcRefusal(
                    SdoAbortCode.DEVICE_STATE, "2045h sub 2 zeroes while running in mode 5 only"
                )
            self._shift_position(-self.position)
        elif subindex in (3, 4):
            absolute = self.position % _P_PER_TURN
            target = absolute if subindex == 3 else absolute - _P_PER_TURN
            self._shift_position(target - self.position)
        else:
            raise EcRefusal(SdoAbortCode.NO_SUBINDEX, f"2045h has no function {subindex}")

    def _shift_position(self, delta: float) -> None:
        self.position += delta
        self.command_position += delta

    # ------------------------------------------------------------------ modes
    def set_mode(self, mode: int) -> None:
        """Apply T_MOD ``mode`` as 2042h does; :class:`EcRefusal` when the rules forbid it."""
        name = MODES.get(mode)
        if name is None:
            raise EcRefusal(SdoAbortCode.INVALID_VALUE, f"mode {mode} is not in T_MOD")
        if 16 <= mode <= 20:
            raise EcRefusal(
                SdoAbortCode.DEVICE_STATE,
                f"customer mode {mode} ({name}) needs its data structures in URAM; "
                "this simulator has none",
            )
        if mode in (28, ERR, 30):
            raise EcRefusal(SdoAbortCode.INVALID_VALUE, f"mode {mode} ({name}) is internal")
        if mode == RES:
            self.network.loop.call_soon(self._reset_if_powered)
            return
        if self.mode == ERR:
            if mode != OFF:
                raise EcRefusal(
                    SdoAbortCode.DEVICE_STATE,
                    "the motor is in error mode 29: mode 1 (OFF) leaves it once the cause is gone",
                )
            if self._trip_causes():
                raise EcRefusal(
                    SdoAbortCode.DEVICE_STATE,
                    "mode 1 cannot leave mode 29: the cause is still there",
                )
        if (
            mode in _POWER_ON_MODES
            and self.mode not in _POWER_ON_MODES
            and abs(self.velocity) >= 0.5
        ):
            raise EcRefusal(
                SdoAbortCode.DEVICE_STATE,
                "the power stage cannot be switched on while the motor turns",
            )
        if mode != self.mode:
            self.command_position = self.position
            self.command_velocity = self.velocity if mode in _POWER_ON_MODES else 0.0
            self.in_position = False
        self.mode = mode

    def _reset_if_powered(self) -> None:
        if self.powered:
            self.hardware_reset()

    def _trip_causes(self) -> int:
        """The protection causes present now (m_sss bits)."""
        causes = 0
        limits = LIMITS
        if self.udc > limits["udc_max"]:
            causes |= BUH
        if self.udc < limits["udc_min"]:
            causes |= BUL
        if self.tsn > limits["tsn_max"]:
            causes |= BTS
        if self.tcu >= limits["tcu_max"]:
            causes |= BTM
        if self.power_stage and self.load > self.torque_limit:
            causes |= BIH
        if self.power_stage and abs(self.command_position - self.position) > limits["p_err_max"]:
            causes |= BEP
        if self.hw_fault:
            causes |= BHW
        return causes

    @property
    def torque_limit(self) -> int:
        """The torque limit (setting 2027h), as a magnitude."""
        return abs(self.settings[0x2027])

    # ------------------------------------------------------------------ physics
    def _step(self, dt: float) -> None:
        if dt <= 0:
            return
        self.time_units += dt * 1000 / 0.8
        causes = self._trip_causes()
        if self.m_set & CEN and not self.bio_input:
            causes |= BEN
        if self.c_sss & (BCER | BCEF):
            causes |= BEK
        self.m_sss |= causes
        tripped = causes & BHW or causes & self.s_err & _SW_CAUSES
        if tripped and self.mode != ERR:
            if not causes & BHW:
                self.m_sss |= BSW
            self.mode = ERR
            self._send_emcy()
        self._move(dt)
        # thermal utilisation: first order towards (torque / rated)^2
        heat = (self.torque / _RATED_TORQUE) ** 2 * 10000
        self.tcu += (heat - self.tcu) * min(1.0, dt / _THERMAL_TIME)

    def _move(self, dt: float) -> None:
        settings = self.settings
        acc = max(1, settings[0x2025]) * _A_TO_V
        dec = max(1, settings[0x2026]) * _A_TO_V
        if self.m_set & CAR:
            dec = acc
        mode = self.mode
        sign = -1 if self.m_set & CDI else 1
        if not self.power_stage:  # coasting; the control follows the rotor
            self.command_velocity = 0.0
            self.velocity = _toward(self.velocity, 0.0, _COAST * dt)
            self.torque = 0.0
            self.position += self.velocity * _V_TO_P * dt
            self.command_position = self.position
            return
        if mode == STP:
            target, rate = 0.0, _STOP
        elif mode == PON:
            target, rate = 0.0, dec
        elif mode == VEL:
            target = sign * settings[0x2024]
            rate = acc if abs(target) > abs(self.command_velocity) else dec
        elif mode == VELP:
            target = sign * self.potentiometer
            rate = acc if abs(target) > abs(self.command_velocity) else dec
        elif mode == POZ:
            target, rate = self._position_profile(acc, dec)
        else:  # MOM: the torque limit drives against the load
            surplus = self.torque_limit - self.load
            top = abs(settings[0x2024]) or 32767
            target, rate = sign * top, max(0.0, surplus) * _MOMENT
        target = self._within_limits(target)
        self.command_velocity = _toward(self.command_velocity, target, rate * dt)
        before = self.command_position
        self.command_position += self.command_velocity * _V_TO_P * dt
        if mode == POZ:
            self._arrive(before)
        if self.load > self.torque_limit:  # the motor cannot hold: it stalls
            self.torque = math.copysign(self.torque_limit, self.command_velocity or 1)
            self.velocity = _toward(self.velocity, 0.0, _COAST * dt)
            self.position += self.velocity * _V_TO_P * dt
        else:  # the rotor follows the control
            accel = (target - self.velocity) / dt if dt else 0.0
            self.velocity = self.command_velocity
            self.torque = self.load + min(abs(accel) * 0.01, self.torque_limit - self.load)
            self.position += self.command_position - before
        if mode == STP and self.command_velocity == 0.0 and abs(self.velocity) < 0.5:
            self.mode = PON
        if mode == POZ and self.in_position and self.m_set & CDN:
            self.mode = PON

    def _goal(self) -> float:
        """The position mode's target, within the position limits when they are on."""
        settings = self.settings
        goal = float(settings[0x2023])
        if self.m_set & CLP:
            goal = max(settings[0x2021], min(settings[0x2022], goal))
        return goal

    def _position_profile(self, acc: float, dec: float) -> tuple[float, float]:
        distance = self._goal() - self.command_position
        top = abs(self.settings[0x2024]) or 32767
        if self.in_position or distance == 0:
            return 0.0, dec
        brake = math.sqrt(2 * dec * abs(distance) / _V_TO_P)
        speed = min(top, brake)
        target = math.copysign(speed, distance)
        rate = acc if abs(target) > abs(self.command_velocity) else dec
        return target, rate

    def _arrive(self, before: float) -> None:
        """The control reaches (or would pass) the goal this step: it stops there (bpo)."""
        goal = self._goal()
        if (before - goal) * (self.command_position - goal) <= 0:
            self.command_position = goal
            self.command_velocity = 0.0
            self.in_position = True

    def _within_limits(self, target: float) -> float:
        if not self.m_set & CLP:
            return target
        low, high = self.settings[0x2021], self.settings[0x2022]
        if target > 0 and self.position >= high:
            self.m_sss |= BLH
            return 0.0
        if target < 0 and self.position <= low:
            self.m_sss |= BLL
            return 0.0
        return target

    # ------------------------------------------------------------------ frames
    def _send_status(self) -> None:
        position = _clamp(self.position, 4, True)
        self._send(status_frame(self.address, position, self.eci, self.m_ssm))

    def _send_emcy(self) -> None:
        self._send(
            emcy_frame(
                self.address,
                self.m_sss,
                self.c_sss,
                self.m_ssm,
                code_as_printed=self.quirks["emcy_code_as_printed"],
            )
        )

    # ------------------------------------------------------------------ outside view
    def physical(self, unit: str, raw: float) -> float:
        """``raw`` in unit class ``unit`` (V, A, D, P, M, C, U, T, K) as a physical value."""
        entry = UNITS.get(unit)
        if entry is None:
            raise SimulationError(f"unit class {unit!r} is unknown: use one of {', '.join(UNITS)}")
        return raw * entry[1]

    def status(self) -> dict[str, Any]:
        return {
            **super().status(),
            "state": f"mode {self.mode} {MODES.get(self.mode, '?')}" if self.powered else "off",
            "mode": self.mode,
            "speed_rpm": round(self.physical("V", self.velocity), 3),
            "position_deg": round(self.physical("P", self.position), 3),
            "torque_nm": round(self.physical("M", self.torque), 4),
            "temperature": round(self.physical("T", self.tsn), 2),
            "thermal_load": round(self.tcu / 100, 1),
            "m_sss": self.m_sss,
            "m_ssm": self.m_ssm,
            "c_sss": self.c_sss,
            "fault": self.mode == ERR,
        }

    def inject(self, fault: str, **params: Any) -> None:
        if fault == "overload":
            torque = params.get("torque")
            raw = 2 * self.torque_limit if torque is None else float(torque) / 0.000135
            self.load = max(0, round(raw))
        elif fault == "overtemperature":
            self.tsn = round(float(params.get("celsius", 90)) * 100)
        elif fault == "supply":
            self.udc = round(float(params["volts"]) * 100)
        elif fault == "hw_protection":
            self.hw_fault = bool(params.get("active", True))
        elif fault == "bio":
            self.bio_input = bool(params.get("level", True))
        else:
            super().inject(fault, **params)


def _toward(value: float, target: float, step: float) -> float:
    if abs(target - value) <= step:
        return target
    return value + math.copysign(step, target - value)
