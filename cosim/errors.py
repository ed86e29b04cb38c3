"""Errors users see. Each names the part or field at fault."""

from __future__ import annotations


class ScenarioError(ValueError):
    """A scenario or world file is malformed; `field` is the dotted path ('camera.vfov_deg')."""

    def __init__(self, field: str, value: object, allowed: str) -> None:
        self.field, self.value, self.allowed = field, value, allowed
        super().__init__(f"{clip(field, 200)}: got {clip(repr(value), VALUE_CHARS)}; "
                         f"allowed: {clip(allowed, 800)}")


VALUE_CHARS = 160      # an error line shows at most this much of the bad value


def clip(text: str, n: int) -> str:
    """`text` cut to about `n` characters (head ... tail) when longer, saying how long."""
    if len(text) <= n:
        return text
    return f"{text[: n * 2 // 3]}...[{len(text)} characters]...{text[-(n // 4):]}"


class ComponentError(RuntimeError):
    """A part of the co-simulation failed; `part` is e.g. 'plant', 'onboard', 'app'."""

    def __init__(self, part: str, message: str) -> None:
        self.part = part
        super().__init__(f"{part}: {message}")


class OutputError(OSError):
    """A run's outputs could not be written (disk full, read-only, ...); names the folder."""


def output_error(exc: OSError, path: object, more: str = "") -> OutputError:
    """The OutputError for a failed write of `path`: 'disk full writing PATH' when the
    device is full, else 'cannot write PATH (reason)'; `more` says what was kept."""
    import errno

    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        text = f"disk full writing {path}"
    else:
        text = f"cannot write {path} ({exc.strerror or exc})"
    return OutputError(text + (f"; {more}" if more else ""))
