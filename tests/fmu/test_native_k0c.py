"""The soil's instantaneous matrices over the compressed history's partition (issue 37, item 4):
D and E compressed with the history (soil_impedance/hhistory.py, ``compress_history(instant=...)``),
and the native stepper's per-step products with E and K0C = D0 + c1 E over the blocks
(fmus/native/stepper.c ``k0c_blocks``, soil.c ``up_hm_matvec``).

Scenes: the reactor stick on a disk raft of 185 nodes (``small_scene(element_size=2.6)``, leaves
of 16 nodes: far blocks at this size) over the rock's springs plus two oscillators with the soil
kernel's structure (``with_kernel_terms``); and the mat of the scene "mat" at 25 x 25 = 625
nodes with the same kind of soil (the default leaves of 32 nodes, compressed from 600 nodes on
as a run compresses it). Checked:

- Python: the compressed D and E against the model's: every far block within their tolerance
  (INSTANT_TOL_FACTOR x the history's, relative to the largest diagonal entry of the matrix's node block), near blocks and the
  rigid border exact; E's far blocks (springs and dashpots: node by node) exactly zero;
- C: the stepper takes the compressed products (``hk``), and they equal the dense products with
  the same matrices (the dense K0C the bases are built from, E of the resource file) to 1e-13 of
  the product's size, at the step size and at half of it (each level's coefficients), on random
  vectors;
- a run: the mat at 625 nodes under a pulse that lifts it, both native, compressed (history, D
  and E, at the default tolerance) against dense: max uplift within 1e-3 relative and the gap
  histories within 1e-3 of the largest gap (the fit tolerance is 1e-2); the history's error falls
  with its tolerance, and the rule before (1e-4 relative to the node blocks' 2-norms) is out of
  that bound (the long-range block's 2-norm is 49 times its diagonal).
"""
import dataclasses
import functools
import subprocess

import numpy as np
import pytest

from helpers import pulse_motion, small_scene, soil_model, with_kernel_terms
from helpers.c_host import compile_harness
from helpers.soil_double import winkler_rational
from helpers.winkler import rock_winkler
from fmus import native_stepper
from soil_impedance.convolution import RecursiveConvolutionSoil
from soil_impedance.hhistory import BORDER, DEFAULT_TOL, INSTANT_TOL_FACTOR, _norm2, _scale
from structure import NewmarkStepper

SCENE = small_scene(element_size=2.6)
XY = np.asarray(SCENE.mesh.xy)
MODEL = with_kernel_terms(soil_model(SCENE), XY)
MOTION = pulse_motion(T=0.8)
TOL = 1e-4
CONTACT = dataclasses.replace(SCENE.contact, precheck=False)

pytestmark = pytest.mark.skipif(native_stepper.library() is None, reason="no C compiler for the native stepper")


def compressed_soil():
    return RecursiveConvolutionSoil(MODEL, MOTION.dt, checked=True, history="hmatrix", xy=XY, history_leaf=16,
                                    history_tol=TOL)


def test_compressed_d_and_e_are_within_the_tolerance_block_by_block():
    soil = compressed_soil()
    inst = soil.compressed.instant
    assert inst is not None and inst.nh == 2
    assert np.array_equal(soil.model.D, inst.dense(0)) and np.array_equal(soil.model.E, inst.dense(1))
    p = inst.perm
    for b, (A0, what) in enumerate(((MODEL.D, "D"), (MODEL.E, "E"))):
        A = np.asarray(A0)[np.ix_(p, p)]
        At = inst.dense(b)[np.ix_(p, p)]
        scale = _scale(A[BORDER:, BORDER:])
        tol = INSTANT_TOL_FACTOR * TOL
        far = 0
        for (r0, nr, c0, nc), r in zip(inst.blocks, inst.ranks[b]):
            blk, got = A[r0:r0 + nr, c0:c0 + nc], At[r0:r0 + nr, c0:c0 + nc]
            if r < 0:
                assert np.array_equal(blk, got), f"{what}: a dense block changed"
                continue
            far += 1
            err = np.linalg.norm(blk - got, 2)
            assert err <= tol * scale, f"{what}: far block error {err / scale:.2e} above {tol}"
            if what == "E":
                assert r == 0 and not np.any(blk), "E's far blocks (the dashpots, node by node) are zero"
        assert far > 20
    assert max(inst.ranks[0]) >= 1                       # D's far blocks are not zero (the kernel terms)


HARNESS = r"""
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "uplift.h"

static double gap(const double *a, const double *b, int n)
{
    double d = 0.0, m = 0.0;
    for (int i = 0; i < n; i++) {
        d = fmax(d, fabs(a[i] - b[i]));
        m = fmax(m, fabs(a[i]));
    }
    return d / m;
}

int main(int argc, char **argv)
{
    FILE *f = fopen(argv[1], "rb");
    fseek(f, 0, SEEK_END);
    long size = ftell(f);
    fseek(f, 0, SEEK_SET);
    unsigned char *buf = malloc(size);
    if (fread(buf, 1, size, f) != (size_t)size)
        return 3;
    fclose(f);
    char err[UP_MSG];
    UpRes r;
    UpSoil soil;
    UpStepper st;
    double levels, n_dof, ag0[3] = {0.0, 0.0, 0.0};
    if (up_res_parse(&r, buf, (size_t)size, "(test)", err) || up_res_scalar(&r, "contact_max_subdiv", &levels, err)
        || up_res_scalar(&r, "n_dof", &n_dof, err) || up_soil_init(&soil, &r, (int)n_dof, (int)levels + 1, 1, err)
        || up_stepper_init(&st, &r, &soil, 0, err)) {
        printf("init: %s\n", err);
        return 2;
    }
    size_t len = up_stepper_state_len(&st) + up_soil_state_len(&soil);
    double *block = calloc(len, sizeof(double)), *saves = calloc((size_t)st.nlev * len, sizeof(double));
    up_stepper_bind(&st, block, block, len, saves);
    up_soil_bind(&soil, block + up_stepper_state_len(&st));
    up_stepper_rest(&st, ag0);
    if (up_stepper_prepare(&st, err))
        return 4;
    int n = soil.n;
    double *x = malloc(n * sizeof(double)), *y0 = malloc(n * sizeof(double)), *y1 = malloc(n * sizeof(double));
    srand(7);
    double worst_k = 0.0, worst_e = 0.0;
    UpSystem *y = &st.sys[0];
    for (int rep = 0; rep < 3; rep++) {
        for (int i = 0; i < n; i++)
            x[i] = (double)rand() / RAND_MAX - 0.5;
        up_symv(y->K0C, NULL, n, x, y0);
        up_hm_matvec(&soil, y->hk_rank, y->hk_data, x, y1);
        worst_k = fmax(worst_k, gap(y0, y1, n));
        up_symv(soil.E, NULL, n, x, y0);
        up_hm_matvec(&soil, soil.hm_de_ranks + soil.hm_nblk, soil.hm_de_data + soil.hm_de_off, x, y1);
        worst_e = fmax(worst_e, gap(y0, y1, n));
    }
    printf("%d %zu %.3e %.3e\n", st.hk, st.hk_len, worst_k, worst_e);
    return 0;
}
"""


@pytest.fixture(scope="module")
def harness(tmp_path_factory):
    """The C harness of the stepper's products, compiled once for the step sizes' tests."""
    return compile_harness(HARNESS, tmp_path_factory.mktemp("k0c"), "harness",
                           ("stepper.c", "soil.c", "linalg.c", "resources.c"))


@pytest.mark.slow
@pytest.mark.parametrize("dt", [MOTION.dt, MOTION.dt / 2])
def test_the_stepper_products_over_the_blocks_equal_the_dense_ones(tmp_path, harness, dt):
    soil = compressed_soil()
    st = NewmarkStepper(SCENE.model(), soil, dt, contact=CONTACT, external_soil=True, ag0=MOTION.acc[0])
    blob = tmp_path / "run.bin"
    blob.write_bytes(native_stepper.encode_run(st))
    out = subprocess.run([str(harness), str(blob)], check=True, capture_output=True, text=True).stdout.split()
    hk, held, err_k, err_e = int(out[0]), int(out[1]), float(out[2]), float(out[3])
    n = soil.n_dof
    assert hk == 1, "the stepper did not take the compressed products"
    assert err_k < 1e-13 and err_e < 1e-13, (err_k, err_e)
    assert 0 < held < n * n                              # the upper blocks only (the mirror through them)


# ---- a run on the mat at 625 nodes ---------------------------------------------------------------
def mat_run(history, instant=True, tol=None, scale=None):
    """(soil, native run) of the mat at 625 nodes under a 20 m/s^2 pulse (0.2 mm of uplift), the soil
    ``history`` ("dense" or "auto": compressed at 625 nodes) at ``tol`` (None: the default), D and E
    compressed with it when ``instant``, the far blocks truncated relative to ``scale`` (None: the rule's
    own, ``hhistory._scale``)."""
    import soil_impedance.convolution as conv
    import soil_impedance.hhistory as hh
    from orchestrator.scene import load_scene
    from soil_impedance.mesh import rectangle_mesh
    scene = load_scene("mat")
    scene = dataclasses.replace(scene, mesh=rectangle_mesh(100.0, 100.0, 4.0))
    xy = np.asarray(scene.mesh.xy)
    model = with_kernel_terms(winkler_rational(rock_winkler(xy, scene.mesh.area, damped=True, match="rocking",
                                                            ky=True)), xy)
    motion = pulse_motion(T=1.0, pga=20.0)
    kwargs = {} if tol is None else {"history_tol": tol}
    with pytest.MonkeyPatch.context() as mp:
        if not instant:                                  # the history compressed, D and E held whole
            mp.setattr(conv, "compressed_model", functools.partial(conv.compressed_model, instant=False))
        if scale is not None:
            mp.setattr(hh, "_scale", scale)
        soil = RecursiveConvolutionSoil(model, motion.dt, checked=True, history=history, xy=xy, **kwargs)
    contact = dataclasses.replace(scene.contact, precheck=False)
    st = NewmarkStepper(scene.model(), soil, motion.dt, contact=contact, external_soil=True, ag0=motion.acc[0])
    return soil, native_stepper.simulate_native(st, motion.acc, [])


@pytest.mark.slow
def test_a_625_node_mat_compressed_equals_dense_within_1e_3_of_max_uplift():
    soil_d, dense = mat_run("dense")
    soil_c, comp = mat_run("auto")
    soil_h, hist = mat_run("auto", instant=False)
    assert soil_c.history_kind == "hmatrix" and soil_c.compressed.instant is not None
    assert soil_c.compressed.settings["tol"] == DEFAULT_TOL
    assert soil_h.compressed.instant is None and soil_d.history_kind == "dense" and soil_c.n_dof == 631
    big = float(dense.gap.max())
    assert big > 1e-4                                    # the pulse lifts the mat (0.2 mm)
    uplift = lambda res: abs(float(res.gap.max()) - big) / big
    gaps = lambda res: float(np.abs(res.gap - dense.gap).max()) / big
    # everything compressed against dense: max uplift within 1e-3 (measured 1.0e-4), the gap histories
    # within 1e-3 of the largest gap (measured 1.9e-4)
    assert uplift(comp) <= 1e-3 and gaps(comp) <= 1e-3, (uplift(comp), gaps(comp))
    # the history alone (measured 1.1e-4) and D and E (at 5e-6) against the same run with them whole
    ref = float(hist.gap.max())
    assert uplift(hist) <= 1e-3
    assert abs(float(comp.gap.max()) - ref) <= 1e-3 * ref
    assert float(np.abs(comp.gap - hist.gap).max()) <= 1e-2 * ref
    # the error is the compression's: a tenth of the tolerance, 6 and 5 times less (measured 1.7e-5, 3.5e-5)
    _, fine = mat_run("auto", instant=False, tol=0.1 * DEFAULT_TOL)
    assert uplift(fine) <= 0.3 * uplift(hist) and gaps(fine) <= 0.3 * gaps(hist), (uplift(fine), gaps(fine))
    # the rule before, 1e-4 relative to each node block's 2-norm: out of the bound (8.2e-3; the 1 Hz
    # oscillator's block, whose 2-norm, the collective mode of its long-range kernel, is 49 times its diagonal)
    _, before = mat_run("auto", instant=False, tol=1e-4, scale=_norm2)
    assert uplift(before) > 5e-3


# ---- a large base's inverse (stepper.c: base_inverse, inverse4) ---------------------------------
INVERSE = r"""
#include <math.h>
#include "stepper.c"
int main(void)
{
    int sizes[4] = {37, 509, 514, 603};
    for (int s = 0; s < 4; s++) {
        int n = sizes[s];
        double *A = malloc(sizeof(double) * n * n), *LU = malloc(sizeof(double) * n * n);
        double *inv0 = malloc(sizeof(double) * n * n), *inv1 = malloc(sizeof(double) * n * n);
        int *piv = malloc(sizeof(int) * n);
        srand(n);
        for (int i = 0; i < n * n; i++)
            A[i] = (double)rand() / RAND_MAX - 0.5;
        for (int i = 0; i < n; i++)
            A[i * n + i] += 0.05 * n;                     /* well conditioned, pivoting still at work */
        memcpy(LU, A, sizeof(double) * n * n);
        if (up_lu(LU, piv, n))
            return 2;
        up_inverse(LU, piv, n, inv0, NULL);
        base_inverse(LU, piv, n, inv1, NULL);
        double d = 0.0, m = 0.0, res = 0.0;
        for (int i = 0; i < n * n; i++) {
            d = fmax(d, fabs(inv0[i] - inv1[i]));
            m = fmax(m, fabs(inv0[i]));
        }
        for (int i = 0; i < n; i++)                       /* A inv1 = I */
            for (int j = 0; j < n; j++) {
                double t = 0.0;
                for (int k = 0; k < n; k++)
                    t += A[i * n + k] * inv1[k * n + j];
                res = fmax(res, fabs(t - (i == j)));
            }
        printf("%d %d %.3e %.3e\n", n, memcmp(inv0, inv1, sizeof(double) * n * n) == 0, d / m, res);
        free(A), free(LU), free(inv0), free(inv1), free(piv);
    }
    return 0;
}
"""


def test_a_large_base_inverse_equals_up_inverse_to_roundoff(tmp_path):
    exe = compile_harness(INVERSE, tmp_path, "inverse", ("soil.c", "linalg.c", "resources.c"))
    rows = [line.split() for line in subprocess.run([str(exe)], check=True, capture_output=True,
                                                     text=True).stdout.splitlines()]
    for n, same, diff, res in rows:
        if int(n) < 512:                                 # below UP_INV4_MIN: up_inverse itself, the same bits
            assert same == "1", n
        else:
            assert float(diff) < 1e-13 and float(res) < 1e-12, (n, diff, res)
