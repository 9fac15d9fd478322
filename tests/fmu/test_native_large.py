"""The native stepper's Newton bases on a larger raft (stepper.c: ``base_at``, ``directions``,
``capacitance``; linalg.c: ``up_inverse``).

A base's contact directions Z_i = base^-1 b_i are solved when node i first enters a capacitance
matrix (the lifting part of the raft), from the base's LU kept for it, instead of for every node
when the base is built; the base's inverse solves the identity unswapped with the forward
substitution trimmed to the columns that are not exact zeros. Both are meant to give the bits of
the former eager path, whatever nodes are solved together and in whatever order. Checked:

- the C kernels: up_lu_solve_many on a subset of the right-hand sides gives each of them the same
  bits as on all of them (so a direction solved alone, or with any others, is the direction the
  eager path solved); up_inverse gives the bits of up_lu_solve_many on the identity with its rows
  swapped (the former up_inverse), on sizes that are not multiples of the kernels' widths;
- the scene: the mat of the scene "mat" at 18 x 18 = 324 nodes on the rock's springs plus two
  oscillators with the soil kernel's structure, under a pulse that lifts more than half of the
  mat (so that both bases, every contact closed and every one open, are built and the
  directions are solved batch by batch as nodes lift): the native stepper equals the Python
  stepper (structure.simulate) within max(1e-10, 100 x its round-off spread)
  (tests/helpers/roundoff.py), with the same Newton counts;
- a replayed run: a run handle that first ran another motion (other nodes lifting, other
  directions solved first, another base built first), rewound, gives the same bits as a new
  handle on every row and Newton count, with and without step halving: every number depends on
  the level and the active set only, not on what the stepper's caches held before.

About 22 s of CPU with the imports on a busy machine (the Python stepper's four runs 3 s, the
kernels' compile 2 s).
"""
import ctypes
import dataclasses
import subprocess
from dataclasses import replace

import numpy as np
import pytest

from helpers import pulse_motion, with_kernel_terms
from helpers.c_host import compile_harness
from helpers.roundoff import assert_within_spread, roundoff_spread
from helpers.soil_double import winkler_rational
from helpers.winkler import rock_winkler
from fmus import native_stepper
from orchestrator.scene import load_scene
from soil_impedance.convolution import RecursiveConvolutionSoil
from soil_impedance.mesh import rectangle_mesh
from structure import NewmarkStepper, simulate

CELLS = 18
SCENE = replace(load_scene("mat"), mesh=rectangle_mesh(100.0, 100.0, 100.0 / CELLS))
XY = np.asarray(SCENE.mesh.xy)
MODEL = with_kernel_terms(winkler_rational(rock_winkler(XY, SCENE.mesh.area, match="rocking", ky=True)), XY)
MOTION = pulse_motion(T=0.6, pga=120.0)
DT = MOTION.dt
CONTACT = dataclasses.replace(SCENE.contact, precheck=False)
NODES = ["top_outer"]

pytestmark = pytest.mark.skipif(native_stepper.library() is None, reason="no C compiler for the native stepper")


def soil():
    return RecursiveConvolutionSoil(MODEL, DT, checked=True)


def stepper(contact=CONTACT, ag=MOTION.acc):
    return NewmarkStepper(SCENE.model(), soil(), DT, contact=contact, external_soil=True, ag0=ag[0])


def python_run(ag):
    return simulate(SCENE.model(), soil(), ag, DT, contact=CONTACT, output_nodes=NODES)


@pytest.fixture(scope="module")
def fast():
    return native_stepper.simulate_native(stepper(), MOTION.acc, NODES)


# ---- the C kernels ---------------------------------------------------------------------------
KERNELS = r"""
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "uplift.h"
int main(void)
{
    int bad = 0;
    for (int n = 37; n <= 83; n += 23) {
        int k = n - 3, sub[5] = {0, 5, 6, k - 9, k - 1};
        double *A = malloc(sizeof(double) * n * n), *inv = malloc(sizeof(double) * n * n);
        double *E = malloc(sizeof(double) * n * n), *B = malloc(sizeof(double) * n * k);
        double *S = malloc(sizeof(double) * n * 5);
        int *piv = malloc(sizeof(int) * n);
        srand(n);
        for (int i = 0; i < n * n; i++)
            A[i] = (double)rand() / RAND_MAX - 0.5 + (i % (n + 1) == 0 ? 0.3 : 0.0);
        for (int i = 0; i < n * k; i++)
            B[i] = (double)rand() / RAND_MAX - 0.5;
        for (int i = 0; i < n; i++)
            for (int a = 0; a < 5; a++)
                S[i * 5 + a] = B[i * k + sub[a]];
        if (up_lu(A, piv, n))
            return 2;
        up_lu_solve_many(A, piv, n, B, k);                 /* every right-hand side */
        up_lu_solve_many(A, piv, n, S, 5);                 /* five of them */
        for (int i = 0; i < n; i++)
            for (int a = 0; a < 5; a++)
                bad |= memcmp(&S[i * 5 + a], &B[i * k + sub[a]], sizeof(double)) != 0;
        for (int i = 0; i < n * n; i++)                    /* the former up_inverse */
            E[i] = i % (n + 1) == 0 ? 1.0 : 0.0;
        up_lu_solve_many(A, piv, n, E, n);
        up_inverse(A, piv, n, inv, NULL);
        bad |= 2 * (memcmp(E, inv, sizeof(double) * n * n) != 0);
        free(A), free(inv), free(E), free(B), free(S), free(piv);
    }
    printf("%d\n", bad);
    return 0;
}
"""


def test_a_direction_solved_with_any_others_and_the_inverse_are_the_bits_of_the_full_solve(tmp_path):
    exe = compile_harness(KERNELS, tmp_path, "kernels", ("linalg.c",))
    out = subprocess.run([str(exe)], check=True, capture_output=True, text=True).stdout.split()
    assert out == ["0"], "1: a subset's solve differs from the full solve; 2: up_inverse differs"


# ---- the stepper -----------------------------------------------------------------------------
def test_the_pulse_lifts_more_than_half_the_mat(fast):
    lifted = (fast.gap > 0).mean(axis=1)
    assert lifted.max() > 0.5 and fast.max_uplift() > 0.01
    assert fast.info["factorisations"] >= 10                 # both bases and many capacitance matrices


def test_native_equals_the_python_stepper_within_the_roundoff_spread(fast):
    ref = python_run(MOTION.acc)
    assert np.array_equal(fast.newton_iters, ref.newton_iters)
    assert_within_spread(fast, ref, roundoff_spread(python_run, MOTION.acc, base=ref))


def _rows(lib, handle, ag):
    nt = ag.shape[0]
    rows = np.empty((nt, lib.up_sim_width(handle)))
    iters = np.empty(nt, np.int64)
    stats = np.zeros(3, np.int64)
    err = ctypes.create_string_buffer(1024)
    rc = lib.up_sim_steps(handle, ag.ctypes.data, 0, nt, rows.ctypes.data, iters.ctypes.data, stats.ctypes.data, err)
    assert rc == 0, err.value
    return rows, iters, stats


@pytest.mark.parametrize("max_iter", [30, 2])
def test_a_replayed_run_is_the_same_bits_whatever_the_caches_held(max_iter):
    """A handle that ran another motion first (the mat rocked the other way, less: other nodes
    lifting, the directions solved in other batches and order, halved steps at other levels),
    then rewound, steps the motion to the bits of a new handle."""
    lib = native_stepper.library()
    contact = dataclasses.replace(CONTACT, max_iter=max_iter, max_subdiv=6)
    ag = np.ascontiguousarray(MOTION.acc)
    other = np.ascontiguousarray(-0.6 * MOTION.acc)
    blob = native_stepper.encode_run(stepper(contact), NODES)
    err = ctypes.create_string_buffer(1024)
    fresh = lib.up_sim_open(blob, len(blob), ag.ctypes.data, err)
    used = lib.up_sim_open(blob, len(blob), other.ctypes.data, err)
    assert fresh and used, err.value
    try:
        ref_rows, ref_iters, ref_stats = _rows(lib, fresh, ag)
        _rows(lib, used, other)
        lib.up_sim_rewind(used, ag.ctypes.data)
        rows, iters, stats = _rows(lib, used, ag)
    finally:
        lib.up_sim_close(fresh)
        lib.up_sim_close(used)
    assert np.array_equal(rows, ref_rows) and np.array_equal(iters, ref_iters)
    assert stats[2] == ref_stats[2]                            # the same steps halved
    if max_iter == 2:
        assert ref_stats[2] > 0                                # the case halves steps
