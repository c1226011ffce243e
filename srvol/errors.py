"""User-facing errors: the CLI prints ``srvol: <message>`` and exits non-zero, no traceback."""


class SrvolError(Exception):
    """A problem with the user's input (a file, an argument), not a bug in srvol."""


class SceneError(SrvolError):
    """A scene folder that does not follow the format of DESIGN.md section 4.

    The message names the file and the problem.
    """
