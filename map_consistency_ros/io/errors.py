"""The one error type for bad input files."""
from pathlib import Path


class InputError(Exception):
    """Bad input that the user must fix; the message names the file and, where known, the line."""

    def __init__(self, source: str, message: str, line: int | None = None) -> None:
        where = f'{source}:{line}' if line is not None else str(source)
        super().__init__(f'{where}: {message}')
        self.source = str(source)
        self.line = line


def not_a_file(path: str | Path) -> InputError:
    """The error for an input file that is not there: a folder where a file was expected, or
    nothing at all.

    Parameters
    ----------
    path: the path given.

    Returns
    -------
    The InputError to raise, naming `path`: 'is a folder, not a file' or 'no such file'.
    """
    return InputError(str(path), 'is a folder, not a file' if Path(path).is_dir() else
                      'no such file')
