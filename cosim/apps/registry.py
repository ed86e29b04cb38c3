"""The offboard apps a scenario can name: built-in names, or a user's `package.module:Class`.

`make_app(spec)` builds one (apps check their parameters in their constructor and raise
ValueError naming `app.params.NAME`); `check_app(spec)` does that at load time and turns the
failure into a ScenarioError naming the field.
"""

from __future__ import annotations

import importlib

from cosim.errors import ComponentError, ScenarioError
from cosim.scenario.records import AppSpec

BUILTIN_APPS = ("line_follower", "scripted", "none")


def make_app(spec: AppSpec):
    """The app object for `spec`, or None for the app 'none'."""
    name = spec.name
    if name == "none":
        return None
    if name == "scripted":
        from cosim.apps.scripted import ScriptedApp

        return ScriptedApp(spec.params)
    if name == "line_follower":
        from cosim.apps.line_follower import LineFollowerApp

        return LineFollowerApp(spec.params)
    mod, _, cls = name.partition(":")
    try:
        return getattr(importlib.import_module(mod), cls)(spec.params)
    except (ImportError, AttributeError) as exc:
        raise ComponentError("app", f"cannot load {name!r}: {exc}") from exc


def check_app(spec: AppSpec):
    """Build the app once, so a bad name or parameter fails at load time (ScenarioError)."""
    try:
        return make_app(spec)
    except ValueError as exc:
        msg = str(exc)
        head, _, rest = msg.partition(":")
        if not head.startswith("app.params"):
            head, rest = "app.params", msg
        rest = rest.strip()
        if rest.startswith("got ") and ";" in rest:  # "got X; expected Y" -> "Y"
            rest = rest.split(";", 1)[1].strip()
        for lead in ("expected ", "allowed: "):
            rest = rest.removeprefix(lead)
        raise ScenarioError(head, _param_value(spec, head), rest) from None
    except Exception as exc:  # ComponentError for an unloadable user app
        raise ScenarioError("app.name", spec.name, f"an importable app ({exc})") from None


def _param_value(spec: AppSpec, path: str) -> object:
    key = path.removeprefix("app.params.").split("[")[0]
    return spec.params.get(key, spec.params)
