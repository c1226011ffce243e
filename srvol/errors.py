"""User-facing errors: the CLI prints ``srvol: <message>`` and exits non-zero, no traceback."""


def one_line(text: str) -> str:
    """``text`` with its non-printable characters (newlines, tabs, escapes) written as Python
    escapes: a name read from a user's file cannot break the one-line error."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


class SrvolError(Exception):
    """A problem with the user's input (a file, an argument), not a bug in srvol.

    Its message is always one line (:func:`one_line`).
    """

    def __init__(self, message: str = ""):
        super().__init__(one_line(str(message)))


class SceneError(SrvolError):
    """A scene folder that does not follow the format of DESIGN.md section 4.

    The message names the file and the problem.
    """
