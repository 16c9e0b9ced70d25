"""The one exception family the command line prints cleanly (exit status 1).

Library code raises these with a message that names the file (or parameter) and
the problem, and where possible says what to do about it.  The CLI prints the
message on one line, without a traceback unless ``--debug`` is given.
"""


class DemtoolError(Exception):
    """Base class: an error whose message is meant for the user."""


class InputError(DemtoolError):
    """An input file is missing, unreadable, or has the wrong content."""


class ParameterError(DemtoolError):
    """A parameter value (option or config key) is invalid."""


class ProcessingError(DemtoolError):
    """The data cannot support the computation (too few matches, degenerate geometry, ...)."""


class OutputError(InputError, OSError):
    """An output cannot be written: folder not writable, disk full, a file in the way.

    Also an :class:`OSError`, so code that tolerates failed writes (a cache) keeps
    tolerating them, while the CLI prints it on one line like every DemtoolError.
    """
