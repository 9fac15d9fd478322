"""What the tests share, imported one way from every test folder: ``from helpers import ...``
(``tests/`` is on the path: ``pythonpath`` in pyproject.toml's [tool.pytest.ini_options]).

  scenes         scenes as dicts (the small tower ``tower``, ``small_reactor``, ``export_tower``),
                 changed section by section (``changed``) or entry by entry (``edited``), written
                 as TOML (``write_scene``) for the command line
  results        ``route_result``: a made-up RouteResult
  fmu_host       a Python host of an FMU in a subprocess (``from helpers.fmu_host import ...``)
  c_host         the plain C hosts of the native FMUs compiled, an FMU unpacked for them
                 (``from helpers.c_host import ...``)
  checks         ``rel``: the error of an array relative to a reference; ``assert_pair_rolls_back``
  winkler        the shared Winkler case: the reactor on a rock disk (``FINE_RAFT``,
                 ``COARSE_RAFT``, ``rock_winkler``)
  motions        ground motions (broadband, pulses)
  cases          the co-simulation tests' small scene, its soil and motions
  soil_double    a rational soil with a history (a test double of the recursive convolution)
  passive_models passive RationalModels from mechanical building blocks
  roundoff       the round-off spread of a run (its input scaled by 1 + k 1e-14) and the
                 comparison of two steppers within it (``from helpers.roundoff import ...``)
  plates         plate rafts: a square plate mesh, the reactor's sticks on a concrete plate, the
                 route tests' small plate scene (``from helpers.plates import ...``)
"""
from pathlib import Path

from .cases import EXPORT_MOTION, pulse_motion, rocks_about_both_axes, small_scene, soil_model, winkler
from .checks import assert_pair_rolls_back, rel
from .motions import broadband, smooth_pulse, stepper_pulse
from .passive_models import kernel_passive_model, oscillator_model, random_passive_model, with_kernel_terms
from .results import route_result
from .scenes import SMALL_REACTOR, TOWER, changed, edited, export_tower, small_reactor, toml_text, tower, write_scene
from .soil_double import TrapezoidRationalSoil, winkler_rational
from .winkler import COARSE_RAFT, FINE_RAFT, RockCase, hysteretic_table, rock_winkler

#: the repository's root and the tests' data folder
ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data"

__all__ = ["COARSE_RAFT", "DATA", "EXPORT_MOTION", "FINE_RAFT", "ROOT", "SMALL_REACTOR", "TOWER", "RockCase", "TrapezoidRationalSoil",
           "assert_pair_rolls_back",
           "broadband", "changed", "edited", "export_tower", "hysteretic_table", "kernel_passive_model", "oscillator_model", "pulse_motion", "random_passive_model", "rel",
           "rock_winkler", "rocks_about_both_axes", "route_result", "small_reactor", "small_scene", "smooth_pulse", "soil_model", "stepper_pulse",
           "toml_text", "tower", "winkler", "winkler_rational", "with_kernel_terms", "write_scene"]
