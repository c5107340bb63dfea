"""native_call: a numpy Generator used inside kernels by its addresses."""

from __future__ import annotations

import numpy as np
from ngpm_runtime.native_call import generator_addresses, generator_at
from numba import njit


@njit(cache=False)
def _draws(at: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = generator_at(at)
    return rng.random(n), rng.standard_normal(n), rng.random(n)


def test_generator_at_draws_what_the_generator_draws() -> None:
    """The kernel's draws are the Python Generator's, and they advance its state: the next
    Python draw is the one after them."""
    rng, twin = np.random.default_rng(7), np.random.default_rng(7)
    at = generator_addresses(rng)
    assert at.dtype == np.int64 and at.shape == (6,)
    for n in (0, 1, 5, 300):
        u, z, v = _draws(at, n)
        np.testing.assert_array_equal(u, twin.random(n))
        np.testing.assert_array_equal(z, twin.standard_normal(n))
        np.testing.assert_array_equal(v, twin.random(n))
    assert rng.random() == twin.random()
    assert rng.bit_generator.state == twin.bit_generator.state
