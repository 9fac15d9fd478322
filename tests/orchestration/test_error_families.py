"""Exit codes by one rule (orchestrator.exit_codes): every error class of the project belongs to
exactly one family of uplift_common.errors, the user's input (exit 2) or a computation that
stopped (exit 1)."""
import importlib
import inspect
import pkgutil
import warnings

import pytest

from uplift_common.errors import ComputationError, UserInputError

from uplift_common.code import PACKAGES


def _project_errors():
    found = {}
    for package in PACKAGES:
        root = importlib.import_module(package)
        for info in pkgutil.walk_packages(root.__path__, prefix=f"{package}."):
            if ".scenes" in info.name:
                continue
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                module = importlib.import_module(info.name)
            for name, cls in inspect.getmembers(module, inspect.isclass):
                # private exceptions are control flow caught in the module that raises them (e.g. a
                # Newton failure that makes the stepper halve its step): they never reach a command
                if (issubclass(cls, BaseException) and not issubclass(cls, Warning) and not name.startswith("_")
                        and cls.__module__.split(".")[0] in PACKAGES):
                    found[f"{cls.__module__}.{cls.__qualname__}"] = cls
    return found


ERRORS = _project_errors()


def test_the_walk_finds_the_known_errors():
    names = {n.rsplit(".", 1)[1] for n in ERRORS}
    assert {"SceneError", "EnsembleError", "ChangedFileError", "OutputPathError", "SetupError", "ConvergenceError",
            "CosimError", "MeshError", "NativeBuildError", "StepRefused", "StateRefused", "FragilityError"} <= names


@pytest.mark.parametrize("name", sorted(ERRORS))
def test_every_error_class_is_in_one_family(name):
    cls = ERRORS[name]
    user, computation = issubclass(cls, UserInputError), issubclass(cls, ComputationError)
    assert user != computation, (f"{name} ({', '.join(b.__name__ for b in cls.__mro__[1:-2])}) is in "
                                 f"{'both families' if user else 'no family'}: make it a subclass of one of "
                                 "uplift_common.errors.UserInputError or ComputationError")
