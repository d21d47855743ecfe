"""
One YAML loader for every file the package reads: plans, experiments, options, parameters.

:func:`load_yaml_file` and :func:`load_yaml_text` parse like ``yaml.safe_load`` (same tags,
same result for every ordinary file) but refuse what a hostile or damaged file could do to
the reader, with a :class:`YamlRefused` error naming the file (and line):

* more than :data:`MAX_YAML_BYTES` (4 MiB) of text: read no further;
* bytes that are not UTF-8: the error gives the byte offset;
* more than :data:`MAX_ALIASES` (100) alias dereferences (``*name``) in one document;
* aliases that stand for more than :data:`MAX_ALIAS_NODES` (100 000) nodes in all when
  expanded (an "alias bomb": a few aliases of aliases that consumers would walk billions of
  times), and an alias of a node that contains it (a recursive document);
* collections nested more than :data:`MAX_DEPTH` (64) levels deep.

Memory and time are bounded by the size cap: the checks run while the document is composed,
so a refusal comes before the document is built. Syntax errors stay ``yaml.YAMLError``
(their marks name the file). libyaml's parser is used when PyYAML has it (speed); the
composing, and so every check, is PyYAML's Python code in either case.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any, Callable, Dict, List, NoReturn, Optional, Type, Union

import yaml
from yaml.composer import Composer
from yaml.constructor import SafeConstructor
from yaml.events import AliasEvent, CollectionStartEvent, NodeEvent
from yaml.parser import Parser as _PyYamlParser
from yaml.reader import Reader as _Reader
from yaml.resolver import Resolver
from yaml.scanner import Scanner as _Scanner

from emfc_ros.core.errors import ConfigError

#: Largest YAML text read [B] (characters for text already decoded).
MAX_YAML_BYTES = 4 * 2**20
#: Alias dereferences allowed in one document.
MAX_ALIASES = 100
#: Nodes that the aliases of one document may stand for, expanded, in all.
MAX_ALIAS_NODES = 100_000
#: Nesting depth of collections allowed.
MAX_DEPTH = 64

_CParser: Optional[type]
try:
    from yaml._yaml import CParser as _CParser  # libyaml: the scanner and parser in C
except ImportError:  # pragma: no cover - PyYAML without libyaml
    _CParser = None


class _PyParser(_Reader, _Scanner, _PyYamlParser):
    """PyYAML's own reader, scanner and parser (``yaml.SafeLoader``'s)."""

    def __init__(self, stream) -> None:
        _Reader.__init__(self, stream)
        _Scanner.__init__(self)
        _PyYamlParser.__init__(self)


class YamlRefused(ConfigError):
    """
    A YAML file or text is refused: too large, not UTF-8, an alias bomb or nested too deep.

    ``key`` is the file (or source) name, so the message starts with it.
    """


def one_line(exc: BaseException) -> str:
    """
    An error's message on one line (PyYAML's span several).

    Parameters
    ----------
    exc : BaseException
        The error.

    Returns
    -------
    str
        Its message with every run of white space made one space.
    """
    return ' '.join(str(exc).split())


def _where(mark) -> str:
    return f'line {mark.line + 1}, column {mark.column + 1}: ' if mark is not None else ''


class _GuardedComposer(Composer):
    """PyYAML's composer, counting aliases, expanded nodes and depth as it composes."""

    #: The parser's, mixed in with the composer (:func:`_loader_class`); where the composer
    #: peeks, the next event is a node's (an alias, a scalar, a collection's start).
    peek_event: Callable[[], NodeEvent]

    def __init__(self) -> None:
        super().__init__()
        self.source = '<text>'
        self._reset()

    def _reset(self) -> None:
        self._aliases = 0
        self._alias_nodes = 0
        self._depth = 0
        self._children: List[int] = []     # expanded size of the children composed so far
        self._sizes: Dict[int, int] = {}   # id(anchored node) -> expanded size (when complete)

    def _refuse(self, mark, problem: str) -> NoReturn:
        raise YamlRefused(self.source, f'{_where(mark)}YAML refused: {problem}')

    def _count(self, size: int) -> None:
        if self._children:
            self._children[-1] += size

    def compose_document(self):  # noqa: D102 - PyYAML's hook
        self._reset()
        return super().compose_document()

    def compose_node(self, parent, index):  # noqa: D102 - PyYAML's hook
        event = self.peek_event()
        if isinstance(event, AliasEvent):
            node = self.anchors.get(event.anchor)
            if node is not None:
                self._aliases += 1
                if self._aliases > MAX_ALIASES:
                    self._refuse(event.start_mark, f'more than {MAX_ALIASES} aliases')
                size = self._sizes.get(id(node))
                if size is None:
                    self._refuse(event.start_mark, f'alias *{event.anchor} refers to a node '
                                                   'that contains it (recursive)')
                self._alias_nodes += size
                if self._alias_nodes > MAX_ALIAS_NODES:
                    self._refuse(event.start_mark, f'the aliases stand for more than '
                                                   f'{MAX_ALIAS_NODES} nodes (an alias bomb)')
                self._count(size)
            return super().compose_node(parent, index)
        collection = isinstance(event, CollectionStartEvent)
        if collection:
            if self._depth >= MAX_DEPTH:
                self._refuse(event.start_mark, f'nested more than {MAX_DEPTH} levels deep')
            self._depth += 1
        self._children.append(0)
        try:
            node = super().compose_node(parent, index)
        finally:
            size = 1 + self._children.pop()
            if collection:
                self._depth -= 1
        if event.anchor is not None:
            self._sizes[id(node)] = size
        self._count(size)
        return node


def _loader_class(parser: Type[Any]) -> type:
    class _Loader(_GuardedComposer, parser, SafeConstructor, Resolver):
        """``yaml.SafeLoader`` (or ``CSafeLoader``'s parser) with the guarded composer."""

        def __init__(self, stream, source: str) -> None:
            parser.__init__(self, stream)
            _GuardedComposer.__init__(self)
            SafeConstructor.__init__(self)
            Resolver.__init__(self)
            self.source = source

    return _Loader


_PyLoader = _loader_class(_PyParser)
_Loader = _loader_class(_CParser) if _CParser is not None else _PyLoader


def load_yaml_text(text: Union[str, bytes], source: str = '<text>') -> Any:
    """
    Parse one YAML document like ``yaml.safe_load``, refusing hostile input.

    Parameters
    ----------
    text : str or bytes
        The YAML text; bytes must be UTF-8.
    source : str
        Where it came from (file name), for error messages.

    Returns
    -------
    Any
        The document (None for an empty text).

    Raises
    ------
    YamlRefused
        If the text is too large, not UTF-8, has too many aliases, expands to too many nodes
        or nests too deep (see the module limits).
    yaml.YAMLError
        If it is not valid YAML.
    """
    source = str(source)
    if len(text) > MAX_YAML_BYTES:
        raise YamlRefused(source, f'YAML refused: larger than {MAX_YAML_BYTES} B')
    if isinstance(text, (bytes, bytearray)):
        try:
            text = bytes(text).decode('utf-8')
        except UnicodeDecodeError as exc:
            raise YamlRefused(source, f'YAML refused: not UTF-8 text (byte '
                                      f'{exc.object[exc.start]:#04x} at offset {exc.start} B)'
                              ) from None
    stream = io.StringIO(text)
    stream.name = source
    loader = _Loader(stream, source)
    try:
        return loader.get_single_data()
    except yaml.MarkedYAMLError as exc:
        # libyaml stops flow collections nested 1000 deep before the composer sees them.
        if 'nesting depth' in str(exc.problem):
            raise YamlRefused(source, f'{_where(exc.problem_mark)}YAML refused: nested more '
                                      f'than {MAX_DEPTH} levels deep') from None
        raise
    except RecursionError:  # defensive: the depth limit comes first
        raise YamlRefused(source, 'YAML refused: nested too deep') from None
    finally:
        loader.dispose()


def load_yaml_file(path: Union[str, Path]) -> Any:
    """
    Read and parse a YAML file like ``yaml.safe_load``, refusing hostile files.

    Reads at most :data:`MAX_YAML_BYTES` + 1 bytes, decodes them as strict UTF-8 and parses
    with :func:`load_yaml_text`.

    Parameters
    ----------
    path : str or pathlib.Path
        The file.

    Returns
    -------
    Any
        The document (None for an empty file).

    Raises
    ------
    OSError
        If the file cannot be read.
    YamlRefused
        If it is too large, not UTF-8 or refused by a limit of :func:`load_yaml_text`; the
        message starts with the file name.
    yaml.YAMLError
        If it is not valid YAML (the marks name the file).
    """
    with open(path, 'rb') as handle:
        data = handle.read(MAX_YAML_BYTES + 1)
    if len(data) > MAX_YAML_BYTES:
        raise YamlRefused(str(path), f'YAML refused: larger than {MAX_YAML_BYTES} B')
    return load_yaml_text(data, str(path))


__all__ = ['load_yaml_file', 'load_yaml_text', 'MAX_ALIASES', 'MAX_DEPTH',
           'MAX_ALIAS_NODES', 'MAX_YAML_BYTES', 'one_line', 'YamlRefused']
