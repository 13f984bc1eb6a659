"""The error and warning types every package of the engine raises (collision, multilevel and taichi_cloth).

Warnings are for the user, not for the developer: `warn(message)` prints one line, `warning: <message>`, the first
time a message occurs in a process, without Python's usual file name and source line. They are still Python
warnings (category EngineWarning), so `warnings.catch_warnings`, `-W error` and `pytest.warns` work as usual.
"""
from __future__ import annotations

import sys
import warnings


class MeshError(ValueError):
    """A mesh is unusable (missing file, empty, non-manifold, NaN vertices, degenerate faces): the message
    names the file and what is wrong. taichi_cloth re-exports this class as taichi_cloth.MeshError."""


class EngineWarning(UserWarning):
    """Something a user should know that does not stop the run (a repaired mesh, a step above the stable bound,
    a known-unstable integrator variant). Printed once per message, as one line."""


def warn(message: str) -> None:
    """Warn once per message text (EngineWarning), as one line `warning: <message>`."""
    warnings.warn(message, EngineWarning, stacklevel=2)


_show_previous = warnings.showwarning


def _show(message, category, filename, lineno, file=None, line=None):
    if isinstance(category, type) and issubclass(category, EngineWarning):
        stream = file if file is not None else sys.stderr
        try:
            stream.write(f"warning: {message}\n")
        except (OSError, AttributeError):  # no usable stderr (e.g. a closed pipe): nothing to show it on
            pass
        return
    _show_previous(message, category, filename, lineno, file, line)


# "once": the first occurrence of each message text is shown, wherever it comes from
warnings.filterwarnings("once", category=EngineWarning)
if getattr(warnings.showwarning, "__name__", "") != "_show":
    warnings.showwarning = _show
