"""Errors raised on bad input. The CLI prints them in one line and exits non-zero."""


class TryonError(Exception):
    """Base class: the message names the bad input and how to fix it."""


class MeshError(TryonError):
    """A cloth or obstacle mesh is unusable (degenerate, non-manifold, NaN, no material coordinates)."""


class FabricError(TryonError):
    """Unknown fabric preset or malformed fabric file / parameters."""


class SceneError(TryonError):
    """A scene description is malformed or inconsistent."""


class InputFileError(TryonError):
    """A file could not be read or has the wrong content."""


class LimitError(TryonError):
    """An input asks for more work or memory than a safety limit allows (`tryon.limits`)."""


class SimulationError(TryonError):
    """The simulation failed in a way retries could not fix (NaN, unresolved collisions)."""


class OutputFolderError(InputFileError):
    """An output folder cannot be used: it holds files tryon did not write, is protected, or is not writable."""
