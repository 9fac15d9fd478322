"""The compressed history (soil_impedance/hhistory.py) through the native runtime (soil.c, records
hm_*) and the FMUs.

Scene: the reactor stick on a disk raft of 185 nodes (``small_scene(element_size=2.6)``) over
the rock's Winkler springs and dashpots with two Maxwell terms, plus two oscillators whose
shapes have the soil kernel's structure (``with_kernel_terms``: low-rank far blocks, as a fit's
residues); a strong pulse lifts the raft. The soil with history = "hmatrix" (leaves of 16 nodes:
far blocks at this size). Checked:

- the native stepper with the compressed history against the Python stepper with it: within the
  scene's round-off spread (tests/helpers/roundoff.py), as the dense path;
- compressed against dense (the fitted model's history held whole), both native: max uplift
  within 1e-3 and the gap histories within 1e-2 of the largest gap (the fit tolerance: 1e-2);
  the raft lifts by 0.6 mm;
- the native FMUs (FMI 2.0 and 3.0, compiled by zig for this host: its cache holds the runtime
  of the other exports) exported with the compressed soil: the records hm_* in the
  resources with its tolerance, fmpy's validator finds nothing, the coupled FMU under
  fmpy.simulate_fmu and (FMI 2.0) the structure and soil FMUs under the project's master (the
  soil FMU stepped alone) equal the in-process native run to 1e-10;
- a resource file whose compressed history does not add up is refused with a message naming it.

About 30 s (the FMUs' validation 7 s; the runtime compiled by zig once, then from its cache).
"""
import dataclasses
import zipfile

import numpy as np
import pytest

from helpers import pulse_motion, rel, small_scene, soil_model, with_kernel_terms
from helpers.roundoff import assert_within_spread, roundoff_spread
from fmus import native_stepper
from fmus.native_build import NativeBuildError, decode_resources, encode_resources
from soil_impedance.convolution import RecursiveConvolutionSoil
from structure import NewmarkStepper, simulate

SCENE = small_scene(element_size=2.6)
XY = np.asarray(SCENE.mesh.xy)
MODEL = with_kernel_terms(soil_model(SCENE), XY)
MOTION = pulse_motion(T=0.8)
DT = MOTION.dt
TOL = 1e-4
KWARGS = {"history": "hmatrix", "xy": XY.tolist(), "history_leaf": 16, "history_tol": TOL}
CONTACT = dataclasses.replace(SCENE.contact, precheck=False)

pytestmark = pytest.mark.skipif(native_stepper.library() is None, reason="no C compiler for the native stepper")


def soil(history="hmatrix"):
    kw = dict(KWARGS, history=history) if history == "hmatrix" else {"history": history}
    return RecursiveConvolutionSoil(MODEL, DT, checked=True, **kw)


def native(history="hmatrix", ag=MOTION.acc):
    st = NewmarkStepper(SCENE.model(), soil(history), DT, contact=CONTACT, external_soil=True, ag0=ag[0])
    return native_stepper.simulate_native(st, ag, SCENE.output.nodes)


def python_run(ag):
    return simulate(SCENE.model(), soil(), ag, DT, contact=CONTACT, output_nodes=SCENE.output.nodes)


@pytest.fixture(scope="module")
def fast():
    return native()


def test_the_case_has_far_blocks_and_lifts():
    s = soil()
    assert s.history_kind == "hmatrix" and int((s.compressed.ranks >= 0).sum()) > 50
    assert s.model.provenance["history"]["storage_ratio"] < 0.6


@pytest.mark.slow
def test_native_compressed_history_equals_the_python_one(fast):
    ref = python_run(MOTION.acc)
    assert ref.max_uplift() > 2e-4
    assert_within_spread(fast, ref, roundoff_spread(python_run, MOTION.acc, base=ref))


def test_compressed_equals_dense_within_the_fit_tolerance(fast):
    dense = native("dense")
    up, ref = fast.max_uplift(), dense.max_uplift()
    assert ref > 2e-4 and abs(up - ref) <= 1e-3 * ref
    assert 0 < np.abs(fast.gap - dense.gap).max() <= 1e-2 * np.abs(dense.gap).max()
    assert rel(fast.raft, dense.raft) <= 1e-2


@pytest.mark.slow
@pytest.mark.parametrize("fmi_version", [2, 3])
def test_native_fmus_carry_the_compressed_history(fast, tmp_path, fmi_version):
    from fmpy import simulate_fmu
    from fmpy.validation import validate_fmu

    from fmus.native_build import build_native_fmus, host_platform
    from orchestrator.export import fmu_data
    data = fmu_data(SCENE, MODEL, DT, MOTION, soil_kwargs={**KWARGS, "checked": True})
    fmus = build_native_fmus(data, tmp_path, coupled=True, fmi_version=fmi_version,
                             platforms=(host_platform(fmi_version),))      # zig: its cache, as every export

    for fmu in (fmus["coupled"], fmus["soil"]):
        assert validate_fmu(str(fmu)) == []
        with zipfile.ZipFile(fmu) as z:
            recs = decode_resources(z.read("resources/uplift.bin"))
        assert recs["hm_tol"] == TOL and recs["hm_perm"].shape == (MODEL.n,)
    raft = ["x[0]", "x[1]", "x[2]", "x[3]", "x[4]", "x[5]"] if fmi_version == 2 else ["x_raft_u", "x_raft_r"]
    res = simulate_fmu(str(fmus["coupled"]), output=["max_uplift"] + raft)
    got = np.column_stack([np.asarray(res[name]).reshape(res.shape[0], -1) for name in raft])
    assert rel(got, fast.raft) <= 1e-10
    assert res["max_uplift"][-1] == pytest.approx(fast.max_uplift(), rel=1e-10)
    if fmi_version == 2:                     # the soil FMU stepped alone (its history of the step after next)
        from orchestrator.master import cosimulate
        pair = cosimulate(fmus["structure"], fmus["soil"], MOTION.acc, DT)
        assert rel(pair.raft, fast.raft) <= 1e-10 and rel(pair.gap, fast.gap) <= 1e-10

def test_an_inconsistent_compressed_history_is_refused():
    st = NewmarkStepper(SCENE.model(), soil(), DT, contact=CONTACT, external_soil=True, ag0=MOTION.acc[0])
    recs = decode_resources(native_stepper.encode_run(st))
    recs["hm_data"] = recs["hm_data"][:-1]
    lib = native_stepper.library()
    with pytest.raises(NativeBuildError, match="compressed soil history"):
        native_stepper._stepped(lib, encode_resources(recs), np.ascontiguousarray(MOTION.acc[:3]), lambda *a: None)
