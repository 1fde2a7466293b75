"""Outputs that appear whole or not at all: written beside their final names, renamed at the end.

Every writer of a report, table, figure, graph or bag writes through `StagedOutputs` (or
`staged`, its one-file form): a reader never sees a half-written file, and a command that fails
leaves nothing of what it started, not even a folder it made for its outputs.
"""
from __future__ import annotations

import errno
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


class StagedOutputs:
    """Files and folders written under temporary names beside their final ones: renamed into
    place together when the `with` block ends normally, all removed, with the folders made for
    them, when it raises.

    Each output is staged in a hidden folder of its own in its final folder, under its final
    name (so writers that read the suffix, such as matplotlib's, see it), and moved into place
    by a rename within the file system. An existing file is replaced; an existing folder is
    never replaced (IsADirectoryError or FileExistsError, before anything is written).
    """

    def __init__(self) -> None:
        self._staged: list[tuple[Path, Path]] = []  # (staging folder, final path)
        self._created: list[Path] = []  # folders made for the outputs, in the order made

    def path(self, final: str | Path) -> Path:
        """Where to write the output that will be `final`.

        Parameters
        ----------
        final: the output's path (a file, or a folder its writer creates); its folder is made
            if missing.

        Returns
        -------
        A path that does not exist yet, in a new hidden folder beside `final`, with the same
        name. Raises IsADirectoryError when `final` is an existing folder, and OSError naming
        `final` when its folder cannot be made or written to.
        """
        final = Path(final)
        if final.is_dir():
            raise IsADirectoryError(errno.EISDIR, 'is a folder; name a file', str(final))
        try:
            self._make_folder(final.parent)
            staging = Path(tempfile.mkdtemp(prefix=f'.{final.name}.', suffix='.partial',
                                            dir=final.parent))
        except OSError as error:  # named after the output, not the staging folder
            raise OSError(error.errno, error.strerror, str(final)) from None
        self._staged.append((staging, final))
        return staging / final.name

    def _make_folder(self, folder: Path) -> None:
        missing = []
        while not folder.exists():
            missing.append(folder)
            folder = folder.parent
        for made in reversed(missing):
            made.mkdir(exist_ok=True)
            self._created.append(made)

    def commit(self) -> None:
        """Move every staged output into place (those never written are skipped).

        Returns
        -------
        None. On an OSError the outputs not yet moved are discarded and the error raised.
        """
        try:
            for staging, final in self._staged:
                written = staging / final.name
                if written.exists():
                    os.replace(written, final)
                shutil.rmtree(staging, ignore_errors=True)
        except OSError as error:
            final = self._final_of(error.filename)
            self.discard()
            if final is not None:
                raise OSError(error.errno, error.strerror, str(final)) from None
            raise
        self._staged.clear()
        self._created.clear()

    def discard(self) -> None:
        """Remove every staged output and the folders made for them (when left empty).

        Returns
        -------
        None.
        """
        for staging, _ in self._staged:
            shutil.rmtree(staging, ignore_errors=True)
        for folder in reversed(self._created):
            try:
                folder.rmdir()
            except OSError:  # not empty: it holds something else by now
                pass
        self._staged.clear()
        self._created.clear()

    def __enter__(self) -> StagedOutputs:
        return self

    def __exit__(self, exc_type, exc, traceback) -> None:
        if exc_type is None:
            self.commit()
            return
        final = self._final_of(exc.filename) if isinstance(exc, OSError) else None
        self.discard()
        if final is not None:  # a writer's error names the output, not its hidden stage
            raise OSError(exc.errno, exc.strerror, str(final)) from None

    def _final_of(self, filename) -> Path | None:
        """The final path of the output whose staging folder holds `filename` (None if none)."""
        if not isinstance(filename, (str, os.PathLike)):
            return None
        written = Path(filename)
        for staging, final in self._staged:
            if written == staging or staging in written.parents:
                return final
        return None


@contextmanager
def staged(final: str | Path) -> Iterator[Path]:
    """One output written whole or not at all (StagedOutputs of one path).

    Parameters
    ----------
    final: the output's path; its folder is made if missing.

    Returns
    -------
    A context manager giving the path to write; on leaving it normally the output is moved
    to `final`, on an exception removed.
    """
    with StagedOutputs() as outputs:
        yield outputs.path(final)
