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


NESTED = """
import os, threadpoolctl
import orchestrator.settings as settings
made = []
real = threadpoolctl.threadpool_limits
threadpoolctl.threadpool_limits = lambda **k: made.append(k["limits"]) or real(**k)
with settings.compute_threads(1):
    with settings.compute_threads(1):
        inner = os.environ["OPENBLAS_NUM_THREADS"]
    after = (os.environ["OPENBLAS_NUM_THREADS"], max(i["num_threads"] for i in threadpoolctl.threadpool_info()))
    with settings.compute_threads(2):
        two = (os.environ["OPENBLAS_NUM_THREADS"], max(i["num_threads"] for i in threadpoolctl.threadpool_info()))
    back = (os.environ["OPENBLAS_NUM_THREADS"], max(i["num_threads"] for i in threadpoolctl.threadpool_info()))
print(made, inner, after, two, back, os.environ.get("OPENBLAS_NUM_THREADS"))
"""


def test_a_block_inside_one_of_the_same_limit_changes_nothing_and_another_limit_applies():
    """compute_threads(1) inside compute_threads(1): no second threadpoolctl limit (the outer one
    holds, also after the inner block ends); compute_threads(2) inside applies its own, and the
    outer's limit and variables come back after it; the environment is restored at the end."""
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS",
                                                             "MKL_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", "import numpy\n" + NESTED], env=env, capture_output=True,
                         text=True, check=True).stdout.strip()
    assert out == "[1, 2] 1 ('1', 1) ('2', 2) ('1', 1) None", out
