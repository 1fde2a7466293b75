"""The package's documentation convention: every public function and every public method of a
public class says what it takes (a `Parameters` section) and what it gives back (`Returns` or
`Yields`), so that a newcomer can use it without reading its body."""
import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / 'map_consistency_ros'
_PROPERTIES = {'property', 'cached_property'}


def _public_functions(tree: ast.Module):
    """(qualified name, node) of the module's public functions and public classes' methods
    (properties and dunders excluded: a property reads as an attribute)."""
    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and not node.name.startswith('_'):
            yield node.name, node
        if isinstance(node, ast.ClassDef) and not node.name.startswith('_'):
            for member in node.body:
                if (isinstance(member, ast.FunctionDef) and not member.name.startswith('_')
                        and not any(isinstance(decorator, ast.Name)
                                    and decorator.id in _PROPERTIES
                                    for decorator in member.decorator_list)):
                    yield f'{node.name}.{member.name}', member


def _missing_sections(function: ast.FunctionDef) -> list[str]:
    arguments = function.args
    names = [argument.arg for argument in
             arguments.posonlyargs + arguments.args + arguments.kwonlyargs
             if argument.arg not in ('self', 'cls')]
    names += [argument.arg for argument in (arguments.vararg, arguments.kwarg) if argument]
    returns_value = function.returns is not None and not (
        isinstance(function.returns, ast.Constant) and function.returns.value is None)
    text = ast.get_docstring(function) or ''
    missing = []
    if names and 'Parameters' not in text:
        missing.append('Parameters')
    if returns_value and 'Returns' not in text and 'Yields' not in text:
        missing.append('Returns')
    return missing


def _undocumented(source: str, module: str) -> list[str]:
    return [f'{module}: {name} lacks {" and ".join(missing)}'
            for name, function in _public_functions(ast.parse(source))
            if (missing := _missing_sections(function))]


def test_every_public_function_documents_its_parameters_and_returns():
    found = []
    for path in sorted(PACKAGE.rglob('*.py')):
        found += _undocumented(path.read_text(), str(path.relative_to(PACKAGE.parent)))
    assert not found, '\n'.join(found)


@pytest.mark.parametrize('source, expected', [
    ('def f(x) -> int:\n    """Sum."""\n', ['m: f lacks Parameters and Returns']),
    ('def f(x) -> None:\n    """Sum.\n\n    Parameters\n    ----------\n    x: one\n    """\n',
     []),
    ('def _f(x) -> int:\n    """Private."""\n', []),
    ('class A:\n    @property\n    def size(self) -> int:\n        """Size."""\n', []),
    ('class A:\n    def grow(self, by: int) -> int:\n        """Grow.\n\n    Returns\n    -----'
     '--\n    size\n    """\n', ['m: A.grow lacks Parameters']),
])
def test_the_check_tells_documented_from_undocumented(source, expected):
    assert _undocumented(source, 'm') == expected
