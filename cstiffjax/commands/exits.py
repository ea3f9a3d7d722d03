"""The command line's exit codes (every command; ``cstiffjax --help`` lists them). A module of
its own, importing nothing: the command line's start-up reads them without the commands'
helpers (:mod:`cstiffjax.commands.common` re-exports them)."""

EXIT_OK = 0  # an answer
EXIT_USAGE = 1  # bad arguments or input files (argparse's own errors too): nothing was computed, nothing written
EXIT_NO_ANSWER = 2  # valid inputs, no valid answer: infeasible, pose outside the frame, a failed solve
EXIT_CHECK = 3  # results written, but part of them is missing or failed the command's own check (stderr: what)
EXIT_WRITE = 4  # an output could not be written (disk full, permission); an earlier output there is unchanged
EXIT_INTERRUPTED = 130  # Ctrl-C (128 + SIGINT, as a shell reports it); nothing half-written is left
