"""What the viewer tests share: an independent box's moments and a free loopback port."""

from __future__ import annotations

import socket

import numpy as np


def uniform_box_moments(half: np.ndarray, mass: float) -> np.ndarray:
    """Principal moments of a uniform box by Gauss-Legendre quadrature of ``(r^2 - x_i^2) dm``.

    Independent of the closed form the code uses; 3 points per axis are exact for the
    quadratic integrand.
    """
    nodes, weights = np.polynomial.legendre.leggauss(3)
    g = [nodes * h for h in half]
    w = np.einsum("i,j,k->ijk", weights, weights, weights) / 8.0  # weights sum to 8 on [-1, 1]^3
    x, y, z = np.meshgrid(*g, indexing="ij")
    return mass * np.array(
        [np.sum(w * (y**2 + z**2)), np.sum(w * (x**2 + z**2)), np.sum(w * (x**2 + y**2))]
    )


def closed_port() -> int:
    """A loopback port nothing listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
