"""The Cool Muscle CM1's stored program for the scanner's four push buttons (Qt-free).
Re-exported by :mod:`impress_gui.hardware.cool_muscle`; the emulator preloads it.
"""

from __future__ import annotations


def scanner_program(
    motor_id: int = 1,
    *,
    home_pulses: int = -1000,
    short_end_pulses: int = -40000,
    long_end_pulses: int = -130000,
    speed_units: int = 4,
    accel_units: int = 100,
) -> list[str]:
    """The thesis' four-button program (appendix B) as command lines; defaults are its values.

    Bank 1 home (zero here, then go to P1), bank 2 stop, bank 3 short run (to P2), bank 4 long
    run (to P3). Assigning the hardware inputs to the banks is done with the motor's own tool.
    """
    s = f".{motor_id}"

    def move(point: int) -> list[str]:
        return [f"P{point}{s}", f"S1{s}", f"A1{s}", f"^{s}"]

    return [
        f"P1{s}={home_pulses}",
        f"P2{s}={short_end_pulses}",
        f"P3{s}={long_end_pulses}",
        f"S1{s}={speed_units}",
        f"A1{s}={accel_units}",
        *[f"B1{s}", f"|2{s}", *move(1), f"END{s}"],
        *[f"B2{s}", f"]{s}", f"END{s}"],
        *[f"B3{s}", *move(2), f"END{s}"],
        *[f"B4{s}", *move(3), f"END{s}"],
    ]
