"""What the command line needs of scenes without loading one: the error of an invalid scene,
the names of the built-in scenes, the TOML reader and the PGA limit a scene may ask for.

``orchestrator.scene`` (which loads and checks a scene: numpy, the mesh, the structure model)
re-exports every name here; ``uplift --help``, ``uplift COMMAND --help`` and ``uplift scene``
import this module only, so that they load none of numpy, scipy or h5py.
"""
from __future__ import annotations

from importlib import resources

try:
    import tomllib
except ModuleNotFoundError:  # Python < 3.11
    import tomli as tomllib

from uplift_common.errors import UserInputError

__all__ = ["MAX_PGA_G", "SceneError", "builtin_scenes", "tomllib"]

#: default limit of the peak ground acceleration a scene may ask for, g ([analysis].max_pga_g):
#: the strongest records ever measured peak near 3-4 g; far beyond, a scale or PGA is a typo
MAX_PGA_G = 5.0


class SceneError(UserInputError):
    """An invalid scene; the message names the scene, the key at fault and how to fix it."""


def builtin_scenes() -> list[str]:
    """The names of the built-in scenes (``orchestrator/scenes/NAME.toml``), sorted."""
    return sorted(p.name[:-5] for p in resources.files("orchestrator.scenes").iterdir()
                  if p.name.endswith(".toml"))
