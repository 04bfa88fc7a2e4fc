"""The table's Monte Carlo is deterministic for a seed, whatever the thread count and batching."""

import numba
import numpy as np

from pbvol_cli.multiple_scattering.layout import Layout
from pbvol_cli.multiple_scattering.simulate import simulate

LAY = Layout(extent=8.0, n_rho=8, n_z=16, n_theta=6, n_phi=6, kill_radius=16.0)


def test_same_seed_same_table_for_any_thread_count_and_batch():
    n0 = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        a = simulate(0.9, 1, 0.5, LAY, 3000, 4)
        numba.set_num_threads(n0)
        b = simulate(0.9, 1, 0.5, LAY, 3000, 4, batch=777)
    finally:
        numba.set_num_threads(n0)
    assert np.array_equal(a[0], b[0]) and a[1] == b[1] and a[2] == b[2]
    c = simulate(0.9, 1, 0.5, LAY, 3000, 5)
    assert not np.array_equal(a[0], c[0])
