"""Control tables of the DYNAMIXEL X-series models the suite supports (Protocol 2.0).

Addresses and sizes are the ones of the official ROBOTIS e-manual control tables (X-series share
one layout for the items used here): e.g. Torque Enable 64, Hardware Error Status 70, Goal Position
116, Present Position 132. Per-model facts (model number, current unit and maximum Current Limit,
nominal supply) come from each model's e-manual page.

Pure data and small helpers: no I/O, no rclpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: name -> (address, size in bytes, signed, writable, eeprom).
ITEMS: dict[str, tuple[int, int, bool, bool, bool]] = {
    "model_number": (0, 2, False, False, True),
    "model_information": (2, 4, False, False, True),
    "firmware_version": (6, 1, False, False, True),
    "id": (7, 1, False, True, True),
    "baud_rate": (8, 1, False, True, True),
    "return_delay_time": (9, 1, False, True, True),  # 2 [us] per unit
    "drive_mode": (10, 1, False, True, True),
    "operating_mode": (11, 1, False, True, True),
    "secondary_id": (12, 1, False, True, True),
    "protocol_type": (13, 1, False, True, True),
    "homing_offset": (20, 4, True, True, True),
    "moving_threshold": (24, 4, False, True, True),
    "temperature_limit": (31, 1, False, True, True),
    "max_voltage_limit": (32, 2, False, True, True),
    "min_voltage_limit": (34, 2, False, True, True),
    "pwm_limit": (36, 2, False, True, True),
    "current_limit": (38, 2, False, True, True),
    "velocity_limit": (44, 4, False, True, True),
    "max_position_limit": (48, 4, False, True, True),
    "min_position_limit": (52, 4, False, True, True),
    "startup_configuration": (60, 1, False, True, True),
    "shutdown": (63, 1, False, True, True),
    "torque_enable": (64, 1, False, True, False),
    "led": (65, 1, False, True, False),
    "status_return_level": (68, 1, False, True, False),
    "registered_instruction": (69, 1, False, False, False),
    "hardware_error_status": (70, 1, False, False, False),
    "velocity_i_gain": (76, 2, False, True, False),
    "velocity_p_gain": (78, 2, False, True, False),
    "position_d_gain": (80, 2, False, True, False),
    "position_i_gain": (82, 2, False, True, False),
    "position_p_gain": (84, 2, False, True, False),
    "bus_watchdog": (98, 1, True, True, False),  # 20 [ms] per unit, -1 when it fired
    "goal_pwm": (100, 2, True, True, False),
    "goal_current": (102, 2, True, True, False),
    "goal_velocity": (104, 4, True, True, False),
    "profile_acceleration": (108, 4, False, True, False),
    "profile_velocity": (112, 4, False, True, False),  # 0.229 [rev/min] per unit, 0 = off
    "goal_position": (116, 4, True, True, False),
    "realtime_tick": (120, 2, False, False, False),
    "moving": (122, 1, False, False, False),
    "moving_status": (123, 1, False, False, False),
    "present_pwm": (124, 2, True, False, False),
    "present_current": (126, 2, True, False, False),
    "present_velocity": (128, 4, True, False, False),
    "present_position": (132, 4, True, False, False),
    "velocity_trajectory": (136, 4, True, False, False),
    "position_trajectory": (140, 4, True, False, False),
    "present_input_voltage": (144, 2, False, False, False),  # 0.1 [V] per unit
    "present_temperature": (146, 1, False, False, False),  # 1 [degC] per unit
}

ADDR_MODEL_NUMBER = 0
ADDR_FIRMWARE_VERSION = 6
ADDR_RETURN_DELAY = 9
ADDR_OPERATING_MODE = 11
ADDR_CURRENT_LIMIT = 38
ADDR_MAX_POSITION_LIMIT = 48
ADDR_MIN_POSITION_LIMIT = 52
ADDR_TORQUE_ENABLE = 64
ADDR_HARDWARE_ERROR = 70
ADDR_BUS_WATCHDOG = 98
ADDR_GOAL_CURRENT = 102
ADDR_PROFILE_VELOCITY = 112
ADDR_GOAL_POSITION = 116
ADDR_PRESENT_CURRENT = 126
ADDR_PRESENT_VELOCITY = 128
ADDR_PRESENT_POSITION = 132
ADDR_PRESENT_VOLTAGE = 144
ADDR_PRESENT_TEMPERATURE = 146

#: The block read every control cycle: Present Current (126) .. Present Temperature (146).
STATE_BLOCK_ADDR = ADDR_PRESENT_CURRENT
STATE_BLOCK_LEN = ADDR_PRESENT_TEMPERATURE + 1 - ADDR_PRESENT_CURRENT  # 21 bytes

#: Operating Mode (11) values.
OPERATING_MODES: dict[str, int] = {
    "current": 0,
    "velocity": 1,
    "position": 3,
    "extended_position": 4,
    "current_based_position": 5,
    "pwm": 16,
}

#: Hardware Error Status (70) bits (X-series), bit -> name.
HARDWARE_ERROR_BITS: dict[int, str] = {
    0: "Input Voltage Error",
    1: "Motor Hall Sensor Error",
    2: "Overheating Error",
    3: "Motor Encoder Error",
    4: "Electrical Shock Error",
    5: "Overload Error",
}

#: Status packet error byte: bit 7 is the Alert flag (Hardware Error Status is non-zero).
ERROR_ALERT = 0x80
#: Status packet error numbers (bits 0..6).
PACKET_ERRORS: dict[int, str] = {
    0x01: "Result Fail",
    0x02: "Instruction Error",
    0x03: "CRC Error",
    0x04: "Data Range Error",
    0x05: "Data Length Error",
    0x06: "Data Limit Error",
    0x07: "Access Error",
}

POSITION_TICKS_PER_REV = 4096
POSITION_CENTER = 2048
TICKS_PER_RAD = POSITION_TICKS_PER_REV / (2.0 * math.pi)
#: Present Velocity / Profile Velocity unit: 0.229 rev/min, in rad/s.
VELOCITY_UNIT_RAD_S = 0.229 * 2.0 * math.pi / 60.0
VOLTAGE_UNIT_V = 0.1
WATCHDOG_UNIT_MS = 20.0


@dataclass(frozen=True)
class ModelSpec:
    """Per-model facts from the model's e-manual page."""

    name: str
    model_number: int
    current_unit_ma: float  # Current Limit / Goal / Present Current unit [mA]
    max_current_limit: int  # maximum Current Limit(38) value, raw units
    nominal_voltage: int  # a typical Present Input Voltage, 0.1 V units (emulator)
    velocity_limit: int  # initial Velocity Limit(44), 0.229 rev/min units
    temperature_limit: int = 70
    fast_sync_min_firmware: int = 46  # Fast Sync Read: X330 fw >= 46, X430/X540 fw >= 45
    min_position: int = 0
    max_position: int = POSITION_TICKS_PER_REV - 1

    @property
    def max_current_ma(self) -> float:
        return self.max_current_limit * self.current_unit_ma


MODELS: dict[str, ModelSpec] = {
    m.name: m
    for m in (
        ModelSpec("XC330-T288", 1220, 1.0, 910, 120, 320),
        ModelSpec("XC330-M288", 1240, 1.0, 2352, 50, 350),
        ModelSpec("XL330-M288", 1200, 1.0, 1750, 50, 445),
        ModelSpec("XM430-W350", 1020, 2.69, 1193, 120, 350, temperature_limit=80,
                  fast_sync_min_firmware=45),
        ModelSpec("XM430-W210", 1030, 2.69, 1193, 120, 330, temperature_limit=80,
                  fast_sync_min_firmware=45),
    )
}
MODELS_BY_NUMBER: dict[int, ModelSpec] = {m.model_number: m for m in MODELS.values()}


def item(name: str) -> tuple[int, int]:
    """(address, size) of a control-table item by name."""
    addr, size, *_ = ITEMS[name]
    return addr, size


def describe_hardware_error(bits: int) -> str:
    """Name the set bits of Hardware Error Status(70), e.g. ``"Overload Error"``."""
    names = [n for b, n in HARDWARE_ERROR_BITS.items() if bits & (1 << b)]
    unknown = bits & ~sum(1 << b for b in HARDWARE_ERROR_BITS)
    if unknown:
        names.append(f"unknown bits 0x{unknown:02x}")
    return ", ".join(names) if names else "none"


def describe_packet_error(error: int) -> str:
    """Describe a status packet error byte (alert flag + error number)."""
    parts = []
    num = error & 0x7F
    if num:
        parts.append(PACKET_ERRORS.get(num, f"error number {num}"))
    if error & ERROR_ALERT:
        parts.append("Alert (hardware error)")
    return ", ".join(parts) if parts else "none"


def ticks_to_rad(ticks: float) -> float:
    """Servo angle [rad] of a position in ticks, 0 rad at the centre tick 2048."""
    return (ticks - POSITION_CENTER) / TICKS_PER_RAD


def rad_to_ticks(rad: float) -> float:
    return rad * TICKS_PER_RAD + POSITION_CENTER
