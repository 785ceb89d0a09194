"""Roboteq PID gain encoding: continuous gains <-> the ``^KP``/``^KI``/``^KD`` register integers.

Source: the Roboteq controller manuals (V1.8 for firmware 1.x, V2.0 for 2.x), SPEC.md erratum 8:

* firmware 1.x stores each gain as an integer 0..255 = gain x 10 (resolution 0.1);
* firmware 2.x stores gain x 1,000,000, an integer 0..2,000,000,000;
* from firmware 2.1 the speed loop drives an inner current (torque) loop, so the speed gains act on a
  current set point, not on the voltage the open-loop step identified. The equivalence between the
  gains designed on the identified voltage-to-speed plant and the firmware's gains therefore holds for
  firmware 1.x and 2.0 only (:func:`gain_equivalence_holds`).

Units assumed for the equivalence (the manuals give the integer encodings, not the loop's internals):
the firmware's speed PID works on normalised quantities (speed command and encoder speed scaled to
+-1000 at ``^MXRPM``; output = power command in +-1000). The plant input of
:mod:`robchair.platform.control` is the open-loop command expressed as the RPM it gives in steady state
(power / 1000 x max RPM), the same
normalisation as the error, so one of our gains equals the firmware gain times ``scale`` = 1 when
``^MXRPM`` is the motor's max RPM and full power gives max RPM. K_i (1/s) and K_d (s) are continuous-time
gains; the firmware's loop scales them by its own sample time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from robchair.platform.control import ControlError, PIDDesign, evaluate_gains, pole_mismatch

FIRMWARE_MULTIPLIER: dict[int, int] = {1: 10, 2: 1_000_000}
"""Register value per unit of gain, by firmware major version."""

FIRMWARE_RANGE: dict[int, tuple[int, int]] = {1: (0, 255), 2: (0, 2_000_000_000)}
"""Inclusive register range of ``^KP``/``^KI``/``^KD`` by firmware major version (manual V1.8 / V2.0)."""

GAIN_EQUIVALENCE_NOTE = (
    "Roboteq gain equivalence holds for firmware 1.x and 2.0 only: from 2.1 the speed loop drives a "
    "current loop, which the identified voltage-to-speed plant does not describe (SPEC erratum 8)"
)


def gain_equivalence_holds(major: int, minor: int) -> bool:
    """True when the firmware's speed gains act on the plant :mod:`robchair.platform.control` identifies.

    Firmware 1.x and 2.0 close the speed loop on the motor voltage; 2.1 and later close it on a current
    loop (SPEC erratum 8), so a design on the open-loop voltage-to-speed plant does not carry over.
    """
    return major == 1 or (major == 2 and minor == 0)


def _check_firmware(firmware_major: int) -> None:
    if firmware_major not in FIRMWARE_MULTIPLIER:
        raise ControlError(f"firmware_major = {firmware_major!r}: expected 1 or 2")


def encode_gain(gain: float, firmware_major: int, name: str = "gain", scale: float = 1.0) -> int:
    """The register integer for one continuous gain: ``round(gain x scale x multiplier)``.

    Args:
        gain: Continuous gain (K_p dimensionless, K_i in 1/s, K_d in s).
        firmware_major: 1 or 2.
        name: Gain name for the error message (``kp``, ``ki``, ``kd``).
        scale: Units scale (see the module docstring).

    Raises:
        ControlError: Unknown firmware, a non-finite gain, or an integer outside :data:`FIRMWARE_RANGE`.
    """
    _check_firmware(firmware_major)
    mult = FIRMWARE_MULTIPLIER[firmware_major]
    lo, hi = FIRMWARE_RANGE[firmware_major]
    if not math.isfinite(gain):
        raise ControlError(f"Roboteq firmware {firmware_major}.x: {name} = {gain!r} is not a finite gain")
    raw = gain * scale * mult
    q = round(raw)
    if q < lo or q > hi:
        raise ControlError(
            f"Roboteq firmware {firmware_major}.x cannot hold {name} = {gain:.6g} (x{mult} = {raw:.6g}): "
            f"the integer must be in {lo}..{hi}; change omega_w / p, or use firmware 2.x"
        )
    return int(q)


def decode_gain(register: int, firmware_major: int, scale: float = 1.0) -> float:
    """The continuous gain a register integer stands for: ``register / multiplier / scale``.

    Raises:
        ControlError: Unknown firmware or an integer outside :data:`FIRMWARE_RANGE`.
    """
    _check_firmware(firmware_major)
    lo, hi = FIRMWARE_RANGE[firmware_major]
    if not lo <= register <= hi:
        raise ControlError(
            f"Roboteq firmware {firmware_major}.x gain register {register!r}: "
            f"expected an integer in {lo}..{hi}"
        )
    return register / FIRMWARE_MULTIPLIER[firmware_major] / scale


@dataclass(frozen=True)
class RoboteqGains:
    """PID gains in Roboteq firmware units and what they do once quantised.

    Attributes:
        kp, ki, kd: Integer firmware values (``^KP``/``^KI``/``^KD``).
        firmware_major: 1 or 2.
        multiplier: 10 (1.x) or 1,000,000 (2.x).
        scale: Units conversion from our RPM-based gains to the firmware's normalised gains.
        effective: The continuous gains the integers stand for, (kp, ki, kd).
        quantised: Evaluation of ``effective`` on the plant (achieved poles, margins, step metrics).
        designed_poles: The poles the unquantised design places.
    """

    kp: int
    ki: int
    kd: int
    firmware_major: int
    multiplier: int
    scale: float
    effective: tuple[float, float, float]
    quantised: PIDDesign
    designed_poles: np.ndarray = field(default_factory=lambda: np.zeros(0), compare=False)

    @property
    def max_pole_shift(self) -> float:
        """Largest |quantised pole - designed pole| / |designed pole|, poles paired to minimise it."""
        return pole_mismatch(self.quantised.achieved_poles, self.designed_poles)


def roboteq_gains(design: PIDDesign, firmware_major: int = 1, scale: float = 1.0) -> RoboteqGains:
    """Convert a design's gains to Roboteq integers and evaluate the quantised controller.

    Args:
        design: The PID design.
        firmware_major: 1 or 2.
        scale: Multiplies the gains before the encoding (see the module docstring).

    Raises:
        ControlError: Unknown firmware, a bad scale, or a gain beyond the firmware's range.
    """
    _check_firmware(firmware_major)
    if not (math.isfinite(scale) and scale > 0):
        raise ControlError(f"scale = {scale!r}: expected a finite number > 0")
    ints = [
        encode_gain(g, firmware_major, name, scale)
        for name, g in (("kp", design.kp), ("ki", design.ki), ("kd", design.kd))
    ]
    kp, ki, kd = (decode_gain(v, firmware_major, scale) for v in ints)
    return RoboteqGains(
        kp=ints[0],
        ki=ints[1],
        kd=ints[2],
        firmware_major=firmware_major,
        multiplier=FIRMWARE_MULTIPLIER[firmware_major],
        scale=scale,
        effective=(kp, ki, kd),
        quantised=evaluate_gains(design.plant, kp, ki, kd),
        designed_poles=design.designed_poles,
    )


def gains_from_roboteq(
    kp: int, ki: int, kd: int, firmware_major: int = 1, scale: float = 1.0
) -> tuple[float, float, float]:
    """Inverse of :func:`roboteq_gains`' encoding: firmware integers -> continuous gains (kp, ki, kd).

    Raises:
        ControlError: Unknown firmware or a register outside :data:`FIRMWARE_RANGE`.
    """
    return (
        decode_gain(kp, firmware_major, scale),
        decode_gain(ki, firmware_major, scale),
        decode_gain(kd, firmware_major, scale),
    )
