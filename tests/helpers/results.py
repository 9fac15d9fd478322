"""A made-up RouteResult for tests of what reads results (reports, summaries, files)."""
import numpy as np

from structure.results import RouteResult, Status


def route_result(route, gap_scale=1.0, wall=1.0, converged=True):
    """300 samples at 10 ms on 6 nodes: rocking at 1 Hz, node 1 lifting (1 mm x gap_scale), a top
    node shaking at 3 and 7 Hz; STOPPED with a message unless ``converged``."""
    nt, N = 300, 6
    t = 0.01 * np.arange(nt)
    xy = np.array([[-5.0, 0.0], [5.0, 0.0], [0.0, 0.0], [0.0, 4.0], [0.0, -4.0], [2.0, 2.0]])
    raft = np.zeros((nt, 6))
    raft[:, 4] = 1e-4 * np.sin(2 * np.pi * t)
    gap = np.zeros((nt, N))
    gap[:, 1] = gap_scale * np.maximum(0.0, 1e-3 * np.sin(2 * np.pi * t))
    acc = {"top": np.column_stack([np.sin(2 * np.pi * 3 * t), 0 * t, 0.2 * np.sin(2 * np.pi * 7 * t)])}
    return RouteResult(route=route, time=t, raft=raft, gap=gap, contact_force=np.ones((nt, N)), acc=acc,
                       status=Status.CONVERGED if converged else Status.STOPPED,
                       message="" if converged else "Newton failed at t = 1.5 s", wall_s=wall, xy=xy)
