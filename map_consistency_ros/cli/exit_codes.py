"""The exit codes of every subcommand, and how a verdict and a batch map onto them.

0 consistent (or success), 1 inconsistent map, 2 bad input, 3 internal error (a fault of this
program, never a verdict), 4 nothing to judge (too few tested pairs for the test to have found
a failure: never 0, never a verdict about the map). A batch exits with the worst code over its
inputs in the order of RANK, not the largest number.
"""
from __future__ import annotations

from collections.abc import Iterable

EXIT_CONSISTENT = 0
EXIT_INCONSISTENT = 1
EXIT_BAD_INPUT = 2
EXIT_INTERNAL_ERROR = 3
EXIT_NOTHING_TO_JUDGE = 4

# outcome of a verdict (core.verdict CONSISTENT, ...) -> exit code
_OF_OUTCOME = {'consistent': EXIT_CONSISTENT, 'inconsistent': EXIT_INCONSISTENT,
               'nothing to judge': EXIT_NOTHING_TO_JUDGE}
# best to worst: a map that fails outranks one that could not be judged; an input that could
# not be read outranks both, and a fault of this program everything
RANK = (EXIT_CONSISTENT, EXIT_NOTHING_TO_JUDGE, EXIT_INCONSISTENT, EXIT_BAD_INPUT,
        EXIT_INTERNAL_ERROR)
NAMES = {EXIT_CONSISTENT: 'consistent', EXIT_INCONSISTENT: 'inconsistent',
         EXIT_BAD_INPUT: 'bad input', EXIT_INTERNAL_ERROR: 'internal error',
         EXIT_NOTHING_TO_JUDGE: 'nothing to judge'}
HELP = ('Exit codes: 0 consistent / success, 1 inconsistent map, 2 bad input,\n'
        '3 internal error (one line on stderr naming the input; its traceback with --debug),\n'
        '4 nothing to judge (too few tested pairs for a verdict; never 0).')


def of_outcome(outcome: str) -> int:
    """The exit code of a verdict's outcome.

    Parameters
    ----------
    outcome: Assessment.outcome ('consistent', 'inconsistent', 'nothing to judge').

    Returns
    -------
    EXIT_CONSISTENT, EXIT_INCONSISTENT or EXIT_NOTHING_TO_JUDGE.
    """
    return _OF_OUTCOME[outcome]


def worst(codes: Iterable[int]) -> int:
    """The worst of several exit codes, by RANK.

    Parameters
    ----------
    codes: exit codes of RANK.

    Returns
    -------
    The code ranked worst; EXIT_CONSISTENT for none.
    """
    return max(codes, key=RANK.index, default=EXIT_CONSISTENT)
