"""The master's bookkeeping and the FMUs' Real bank: a failure mid-run hands back exactly the
steps done, bad ground motion is refused up front, and the memoised value-reference index
of the bank never confuses two lists."""
import numpy as np
import pytest

from helpers import EXPORT_MOTION
from fmus.real_variables import RealBank
from orchestrator.master import CosimError, FmuSlave, cosimulate

MOTION = EXPORT_MOTION                 # the motion of the shared ``exported`` pair (conftest)


def test_failure_mid_run_keeps_the_steps_done(exported):
    dt, fail_at = MOTION.dt, 40                      # the soil's step 40 -> 41 fails
    full = cosimulate(exported.structure, exported.soil, MOTION.acc, dt)
    with FmuSlave(exported.structure, "structure") as S, FmuSlave(exported.soil, "soil") as G:
        step = G.do_step

        def failing(t, h):
            if t >= fail_at * dt - 1e-12:
                raise CosimError("FMU 'soil': step failed (injected)")
            step(t, h)

        G.do_step = failing
        cut = cosimulate(S, G, MOTION.acc, dt)
    assert full.converged and full.nt == MOTION.acc.shape[0] and full.max_uplift() > 1e-3
    assert not cut.converged and "injected" in cut.message
    # the structure had done step 41 when the soil failed: kept are the steps both FMUs did
    assert cut.nt == fail_at + 1
    assert np.array_equal(cut.raft, full.raft[:fail_at + 1])
    assert np.array_equal(cut.gap, full.gap[:fail_at + 1])
    assert np.array_equal(cut.energy["input"], full.energy["input"][:fail_at + 1])
    assert np.array_equal(cut.newton_iters, full.newton_iters[:fail_at + 1])
    for part in ("initialisation", "structure step", "soil step", "transfers"):
        assert cut.notes.timings[part] > 0 and cut.info["timing_cpu"][part] >= 0


@pytest.mark.parametrize("ag, what", [(np.zeros((10, 2)), "shape"), (np.full((10, 3), np.nan), "NaN")])
def test_bad_ground_motion_is_refused(exported, ag, what):
    with pytest.raises(ValueError, match=f"ground acceleration ag.*{what}"):
        cosimulate(exported.structure, exported.soil, ag, MOTION.dt)


def test_bank_index_is_exact():
    bank = RealBank()
    bank.grow(10)
    bank.values[:] = np.arange(10.0)
    assert bank.index([2, 3, 4]) == slice(2, 5)
    # same length, first and last value reference as a memoised list, other middle
    for vrs in ([2, 7, 4], [2, 3, 4], [2, 0, 4]):
        assert bank.values[bank.index(list(vrs))].tolist() == [float(v) for v in vrs]
    assert bank.values[bank.index([])].size == 0
    assert bank.values[bank.index(np.array([2, 9, 4]))].tolist() == [2.0, 9.0, 4.0]
    with pytest.raises(IndexError, match="Real variables of this FMU are 0..9"):
        bank.index([8, 9, 10])


@pytest.mark.parametrize("pair", ["exported", "exported_native"])
def test_model_description_reads_as_fmpy_reads_it(request, pair):
    """The master's one-pass read of an FMI 2.0 model description gives what fmpy's reader gives."""
    from fmpy import read_model_description
    exp = request.getfixturevalue(pair)
    for path in (exp.structure, exp.soil):
        ref = read_model_description(str(path))
        with FmuSlave(path) as fmu:
            md = fmu.md
        assert (md.fmiVersion, md.guid, md.modelName, md.generationTool, md.coSimulation.modelIdentifier) == \
            (ref.fmiVersion, ref.guid, ref.modelName, ref.generationTool, ref.coSimulation.modelIdentifier)
        fields = ("name", "valueReference", "type", "causality")
        got = [tuple(getattr(v, f) for f in fields) for v in md.modelVariables]
        assert got == [tuple(getattr(v, f) for f in fields) for v in ref.modelVariables] and len(got) > 100


def test_native_resource_copied_exactly_and_a_damaged_one_refused(exported_native, tmp_path):
    """extract_fmu copies the native resource file out of the archive without zipfile's CRC pass:
    the copy is the archive's bytes, and a file with one bit flipped is refused by the runtime's own
    checksum when the FMU is instantiated (a CosimError naming the file and the fix)."""
    import zipfile
    from pathlib import Path

    from orchestrator.master import NATIVE_RESOURCE
    path = Path(exported_native.soil)
    with zipfile.ZipFile(path) as z:
        info, stored = z.getinfo(NATIVE_RESOURCE), z.read(NATIVE_RESOURCE)
    assert info.compress_type == zipfile.ZIP_STORED and len(stored) > 1000
    with FmuSlave(path, "soil") as fmu:
        assert (Path(fmu.dir) / NATIVE_RESOURCE).read_bytes() == stored
    data = bytearray(path.read_bytes())
    head = info.header_offset
    start = head + 30 + int.from_bytes(data[head + 26:head + 28], "little") + int.from_bytes(data[head + 28:head + 30], "little")
    assert bytes(data[start:start + len(stored)]) == stored
    data[start + len(stored) // 2] ^= 1
    bad = tmp_path / "soil.fmu"
    bad.write_bytes(bytes(data))
    with pytest.raises(CosimError, match=r"uplift.bin is damaged \(checksum\): export the FMU again"):
        FmuSlave(bad, "soil")
