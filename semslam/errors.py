"""One root exception, one subclass per area.

The CLI turns every ``SemslamError`` into a single line on stderr and a
non-zero exit code; anything else is a bug and keeps its traceback.
Messages say what was wrong and where (file, line, field).
"""


class SemslamError(Exception):
    """Root of every error semslam raises on purpose."""


class FormatError(SemslamError):
    """A file exists but its content is broken (syntax, schema, version, values)."""


class DriveError(SemslamError):
    """A drive folder is incomplete or inconsistent (missing files, time going backwards)."""


class MapError(FormatError):
    """A map file is broken or of an unsupported version."""


class ConfigError(SemslamError):
    """A configuration value or file is invalid."""


class SimulationError(SemslamError):
    """The simulator was asked for something it cannot build."""


class PerceptionError(SemslamError):
    """A detector was given input it cannot use (image type, shape, family, intrinsics)."""


class MarkingInputError(PerceptionError, ValueError):
    """The painted-line detector was given an image, mask, prior or parameter it cannot use
    (also a ``ValueError``, as numpy's own argument errors are)."""


class MappingError(SemslamError):
    """The mapper could not solve its factor graph (an indeterminate system)."""
