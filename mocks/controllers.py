"""The twin's controllers other than the in-process one of `run --sim`: for `trackcal mock`, a mock server package
with a `twin_controller` module serves the twin's robot behind that controller family's own protocols (its
CONTROLLER: the family name a robot config's `controller` key gives, as the hardware file's robot.protocol does;
`serve(world, seed)` starts it with the robot at the world's joints and keeps the world's robot where the
controller reports it). Found by walking mocks/servers/, so no code outside a family's package names it."""

from __future__ import annotations

import importlib
import importlib.util
import pkgutil

import trackcal.mocks.servers as _servers


def twin_controllers() -> dict[str, object]:
    """family name -> its twin_controller module."""
    out: dict[str, object] = {}
    for info in pkgutil.iter_modules(_servers.__path__):
        name = f"{_servers.__name__}.{info.name}.twin_controller"
        if info.ispkg and importlib.util.find_spec(name) is not None:
            module = importlib.import_module(name)
            out[module.CONTROLLER] = module
    return out
