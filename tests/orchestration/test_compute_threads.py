"""compute_threads limits every BLAS pool a computation uses, also one whose library loads inside
the block (scipy's, imported on first use): otherwise its size, and the round-off, would follow
the machine's cores."""
import os
import subprocess
import sys

CHILD = """
import numpy, threadpoolctl
from orchestrator.settings import compute_threads
with compute_threads(1):
    import scipy.linalg                      # scipy's own OpenBLAS loads here, inside the block
    sizes = {i["filepath"]: i["num_threads"] for i in threadpoolctl.threadpool_info()}
print(max(sizes.values()), len(sizes))
print(os.environ.get("OPENBLAS_NUM_THREADS"))
"""


def test_a_blas_loaded_inside_the_block_runs_at_its_limit():
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS",
                                                             "MKL_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", "import os\n" + CHILD], env=env, capture_output=True,
                         text=True, check=True).stdout.split("\n")
    largest, pools = map(int, out[0].split())
    assert pools >= 1 and largest == 1, out
    assert out[1] == "None"                  # the environment is restored after the block
