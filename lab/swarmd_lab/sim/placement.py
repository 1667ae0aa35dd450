"""Where the drones hover: on a line (the paper's section 5.2 set-up), a square grid, or
uniformly at random in a square. Positions are metres in a plane; altitude is ignored."""

from __future__ import annotations

import math
import random
from typing import Final

import numpy as np

from swarmd_lab.sim.phy import FloatArray

PLACEMENTS: Final = ("line", "grid", "random")


def place(kind: str, n: int, spacing_m: float, rng: random.Random) -> FloatArray:
    """``n`` positions, shape (n, 2).

    line: x = i * spacing (the paper puts UAVs "linearly along the x-axis" from the commander);
    grid: ceil(sqrt(n)) columns at ``spacing``; random: uniform in the square the grid would
    fill, so the density matches the grid's.
    """
    if n < 1:
        raise ValueError(f"--n {n}: a swarm needs at least one drone")
    if spacing_m <= 0:
        raise ValueError(f"--spacing {spacing_m}: use a positive distance in metres")
    if kind == "line":
        xs = [i * spacing_m for i in range(n)]
        return np.array([[x, 0.0] for x in xs], dtype=np.float64)
    cols = math.ceil(math.sqrt(n))
    if kind == "grid":
        return np.array(
            [[(i % cols) * spacing_m, (i // cols) * spacing_m] for i in range(n)],
            dtype=np.float64,
        )
    if kind == "random":
        side = max(cols - 1, 1) * spacing_m
        return np.array(
            [[rng.uniform(0.0, side), rng.uniform(0.0, side)] for _ in range(n)],
            dtype=np.float64,
        )
    raise ValueError(f"--placement {kind!r}: use one of {', '.join(PLACEMENTS)}")


def distances(positions: FloatArray) -> FloatArray:
    """Pairwise distance matrix, shape (n, n)."""
    diff = positions[:, None, :] - positions[None, :, :]
    result: FloatArray = np.sqrt((diff**2).sum(axis=-1))
    return result
