"""
Docstrings of the core's public API in numpydoc form, checked on the source (AST only).

Every public function and method of ``emfc_ros/core`` (module and name not starting with
``_``, defined there, methods of public classes included; dunder methods other than
``__init__`` exempt) has a docstring with a ``Parameters`` section naming each parameter
but ``self``/``cls`` (``*args`` and ``**kwargs`` with or without their stars, several names
on one line as ``a, b : float``), and a ``Returns`` or ``Yields`` section when it returns
something other than None: by its return annotation when it has one, else by a ``return
<value>`` or ``yield`` in its body. ``__init__``'s parameters may be in the class docstring
(numpydoc's convention) or its own. A property needs a docstring only; setters, deleters
and ``typing.overload`` stubs are exempt.
"""

import ast
from pathlib import Path
import re
import textwrap

REPO = Path(__file__).resolve().parents[1]
CORE = REPO / 'emfc_ros' / 'core'
#: emfc_ros/core/ident is being split by concern (issue 26 item 1); its docstrings are
#: checked after the split.
EXCLUDED = (CORE / 'ident',)

_HEADER = re.compile(r'^\s*-{3,}\s*$')
_PARAM_SECTIONS = ('Parameters', 'Other Parameters')
_RETURN_SECTIONS = ('Returns', 'Yields')
_NONE_ANNOTATIONS = ('None', 'NoReturn', 'Never')


def _sections(doc: str) -> dict:
    """Section title to its lines (numpydoc: a title underlined with dashes)."""
    lines = textwrap.dedent(doc).splitlines()
    sections, current = {}, None
    for i, line in enumerate(lines):
        if i + 1 < len(lines) and _HEADER.match(lines[i + 1]) and line.strip():
            current = line.strip()
            sections[current] = []
        elif current is not None and not _HEADER.match(line):
            sections[current].append(line)
    return sections


def _documented_names(doc: str) -> set:
    """The names of the entries (lines not indented) of the parameter sections."""
    names = set()
    for title, lines in _sections(doc).items():
        if title in _PARAM_SECTIONS:
            for line in textwrap.dedent('\n'.join(lines)).splitlines():
                if line.strip() and not line[0].isspace():
                    names.update(n.strip().lstrip('*') for n in line.split(':')[0].split(','))
    return names


def _own_nodes(node):
    """The nodes of a function's body, without those of nested functions and classes."""
    stack = list(node.body)
    while stack:
        child = stack.pop()
        yield child
        if not isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef,
                                  ast.Lambda)):
            stack.extend(ast.iter_child_nodes(child))


def _returns_value(func) -> bool:
    if func.returns is not None:
        text = ast.unparse(func.returns).strip('\'"')
        return text.split('.')[-1] not in _NONE_ANNOTATIONS
    return any(isinstance(n, (ast.Yield, ast.YieldFrom)) or (
        isinstance(n, ast.Return) and n.value is not None and not (
            isinstance(n.value, ast.Constant) and n.value.value is None))
        for n in _own_nodes(func))


def _decorators(func) -> set:
    return {ast.unparse(d).split('(')[0] for d in func.decorator_list}


def _check_function(func, where: str, qualname: str = '', class_doc: str = '') -> list:
    """Problems of one function (``qualname`` and ``class_doc`` given for a method)."""
    name, deco = func.name, _decorators(func)
    if name.startswith('_') and name != '__init__' or 'overload' in deco or \
            'typing.overload' in deco or any(d.endswith(('.setter', '.deleter')) for d in deco):
        return []
    doc = ast.get_docstring(func) or ''
    at = f'{where}:{func.lineno} {qualname + "." if qualname else ""}{name}'
    if any(d.split('.')[-1] in ('property', 'cached_property') for d in deco):
        return [] if doc else [f'{at}: missing docstring']
    if not doc and not (name == '__init__' and class_doc):
        return [f'{at}: missing docstring']
    args = func.args
    params = [a.arg for a in args.posonlyargs + args.args + args.kwonlyargs]
    params += [a.arg for a in (args.vararg, args.kwarg) if a is not None]
    if qualname and params and params[0] in ('self', 'cls'):
        params = params[1:]
    documented = _documented_names(doc) | (_documented_names(class_doc)
                                           if name == '__init__' else set())
    problems = [f'{at}: missing parameter {p}' for p in params if p not in documented]
    if name != '__init__' and _returns_value(func) and not any(
            s in _RETURN_SECTIONS for s in _sections(doc)):
        problems.append(f'{at}: missing Returns')
    return problems


def check_source(source: str, where: str) -> list:
    """
    Docstring problems of one module's public functions and methods.

    Parameters
    ----------
    source : str
        The module's source text.
    where : str
        Its path (for the messages, ``path:line name: problem``).

    Returns
    -------
    list of str
        One message per problem, none when clean.
    """
    problems = []

    def visit_class(cls, qualname):
        class_doc = ast.get_docstring(cls) or ''
        for item in cls.body:
            if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)):
                problems.extend(_check_function(item, where, qualname, class_doc))
            elif isinstance(item, ast.ClassDef) and not item.name.startswith('_'):
                visit_class(item, f'{qualname}.{item.name}')

    # module level, including definitions under `if` and `try` (an optional import's
    # fallback, say)
    stack = list(reversed(ast.parse(source, filename=where).body))
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            problems.extend(_check_function(node, where))
        elif isinstance(node, ast.ClassDef) and not node.name.startswith('_'):
            visit_class(node, node.name)
        elif isinstance(node, (ast.If, ast.Try)):
            blocks = [node.body, node.orelse] + [h.body for h in getattr(node, 'handlers', ())]
            stack.extend(reversed([n for b in blocks for n in b]))
    return problems


def _public_modules() -> list:
    paths = []
    for path in sorted(CORE.rglob('*.py')):
        parts = path.relative_to(CORE).parts
        private = any(p.startswith('_') for p in parts[:-1]) or (
            path.name.startswith('_') and path.name != '__init__.py')
        if not private and not any(path.is_relative_to(e) for e in EXCLUDED):
            paths.append(path)
    return paths


def test_core_public_api_documents_parameters_and_returns():
    paths = _public_modules()
    assert len(paths) > 50, 'the core package should hold its modules'
    problems = []
    for path in paths:
        problems += check_source(path.read_text(), str(path.relative_to(REPO)))
    assert not problems, f'{len(problems)} docstring problems:\n' + '\n'.join(problems)


def test_the_checker_fails_on_a_missing_parameter_and_a_missing_returns():
    source = textwrap.dedent('''
        def scaled(x_V, gain=2.0, *args, **kwargs) -> float:
            """
            Scale.

            Parameters
            ----------
            x_V : float
                Input in volts.
            *args, **kwargs
                Ignored.
            """
            return gain * x_V

        def untyped(a):
            """
            No annotation, a value returned.

            Parameters
            ----------
            a : int
                Anything.
            """
            return a

        class Public:
            """
            Its constructor's parameters here.

            Parameters
            ----------
            length_m : float
                A length in metres.
            """

            def __init__(self, length_m, width_m):
                self.length_m = length_m

            @property
            def area(self):
                return self.length_m

            def __repr__(self):
                return 'Public()'

            def _private(self, y):
                return y

            def done(self) -> None:
                """Nothing to document."""

        def _hidden(z):
            return z
    ''')
    assert check_source(source, 'm.py') == [
        'm.py:2 scaled: missing parameter gain',
        'm.py:2 scaled: missing Returns',
        'm.py:15 untyped: missing Returns',
        'm.py:36 Public.__init__: missing parameter width_m',
        'm.py:40 Public.area: missing docstring',
    ]
