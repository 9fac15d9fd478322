"""EXPERIMENTAL solvers of the whole-range contact equation, kept for study: reached only by
name through ``orchestrator.timefreq.METHODS`` (``SolveOptions(method=...)``), never a
default, and ``solve`` warns (``ExperimentalMethodWarning``) when one is used.

============== ===============================================================================
newton_krylov  semi-smooth Newton-Krylov (fails from 0.4 g on the Winkler raft)
paper          the paper's quasi-Newton (fails from 0.2 g on the Winkler raft)
============== ===============================================================================
"""
