"""The one error type for bad input files."""


class InputError(Exception):
    """Bad input that the user must fix; the message names the file and, where known, the line."""

    def __init__(self, source: str, message: str, line: int | None = None) -> None:
        where = f'{source}:{line}' if line is not None else str(source)
        super().__init__(f'{where}: {message}')
        self.source = str(source)
        self.line = line
