"""Exceptions raised by cstiffjax, all subclasses of ``ValueError`` or ``RuntimeError``."""


class RobotFileError(ValueError):
    """A robot description (TOML) is malformed: the message names file, key and line."""


class RecordingsError(ValueError):
    """A recordings CSV is malformed: the message names file, row and column."""


class NoAnswerError(RuntimeError):
    """Valid inputs without a valid answer: no feasible tensions, a pose outside the anchors'
    frame, a solve that failed. The message says which and what would change it (the command
    line's exit code 2)."""


class SolverError(NoAnswerError):
    """A solve (forward statics, catenary, fit) did not converge or hit a degenerate case."""


class OutputPathError(ValueError):
    """An output path would overwrite an input, has the wrong kind (file/folder) or cannot be written."""


class DiagnosisError(ValueError):
    """The recordings cannot support a diagnosis (no equilibrium, samples out of order)."""
