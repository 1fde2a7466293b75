"""The progress bar: drawn on a terminal only."""
import io

from map_consistency_ros.cli.progress import ProgressBar


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_the_bar_is_drawn_on_a_terminal_and_nowhere_else():
    log = io.StringIO()
    with ProgressBar('judging', stream=log) as progress:
        for done in range(1, 5):
            progress(done, 4)
    assert log.getvalue() == ''
    terminal = _Terminal()
    with ProgressBar('judging', stream=terminal) as progress:
        for done in range(1, 5):
            progress(done, 4)
    drawn = terminal.getvalue()
    assert drawn.count('\r') == 4 and ' 4/4 ' in drawn and drawn.endswith('s\n')
    quiet = _Terminal()
    with ProgressBar('judging', stream=quiet, enabled=False) as progress:
        progress(1, 4)
    assert quiet.getvalue() == ''
