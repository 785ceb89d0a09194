"""Root locus of a PID design through python-control (``control.root_locus_map``).

python-control is imported by the functions (see :mod:`robchair.platform.control.design`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from robchair.platform.control.design import PIDDesign

if TYPE_CHECKING:
    import control as ct


def loop_tf(design: PIDDesign) -> ct.TransferFunction:
    """The open loop L(s) = C(s) G(s) of ``design`` (ideal PID times the plant)."""
    return design.controller_tf() * design.plant.tf()


def root_locus(design: PIDDesign, gains: npt.ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Closed-loop poles of 1 + k C(s) G(s) = 0 along the loop gain k, by python-control.

    k = 1 is the design itself; k = 0 gives the open-loop poles (the plant's two and the PID's
    integrator at the origin).

    Args:
        design: The PID design.
        gains: Loop gains k (>= 0); None lets python-control choose them to show the locus's features.

    Returns:
        (loci, gains): ``loci`` complex, shape (len(gains), 3), the poles at each gain (each column
        follows one branch); ``gains`` shape (len(gains),).
    """
    import control as ct

    k = None if gains is None else np.asarray(gains, dtype=float).ravel()
    data = ct.root_locus_map(loop_tf(design), gains=k)
    return np.asarray(data.loci, dtype=complex), np.asarray(data.gains, dtype=float)


def open_loop_poles_and_zeros(design: PIDDesign) -> tuple[np.ndarray, np.ndarray]:
    """Poles and zeros of L(s) = C(s) G(s), where the locus starts and where it ends."""
    import control as ct

    sys = loop_tf(design)
    return np.asarray(ct.poles(sys), dtype=complex), np.asarray(ct.zeros(sys), dtype=complex)
