"""A command's imports in a fresh process run without the cyclic collector, their objects frozen
after them; the command's own garbage cycles are collected as before."""
import subprocess
import sys

PROBE = r"""
import gc, weakref
from orchestrator.cli import _loading

class Cycle:
    pass

assert gc.isenabled()
with _loading(False):                           # a process that has loaded numpy already: nothing changes
    assert gc.isenabled()
assert gc.get_freeze_count() == 0
with _loading(True):
    assert not gc.isenabled()
    made = [Cycle() for _ in range(5000)]
    import json, numpy                          # an import inside the block
frozen = gc.get_freeze_count()
assert gc.isenabled() and frozen >= 5000, frozen
a = Cycle(); a.me = a
ref = weakref.ref(a)
del a
gc.collect()
assert ref() is None                            # a cycle made after the block is collected
assert gc.get_freeze_count() == frozen
gc.disable()
with _loading(True):
    pass
assert not gc.isenabled()                       # the collector is back as it was
print("ok")
"""


def test_loading_freezes_what_the_imports_made_and_keeps_collecting_after():
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr
