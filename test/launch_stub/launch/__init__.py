"""
Test stand-in for ROS 2 Jazzy's ``launch`` package: the subset our launch files use.

``launch`` and ``launch_ros`` cannot be installed from PyPI, so ``test/nodes/
test_launch_files.py`` puts ``test/launch_stub`` on ``sys.path`` and evaluates the installed
launch files against this package; the installed ``emfc_ros`` never imports it. Each piece
mirrors the source (github.com/ros2/launch, ros2/launch_ros; read at launch_ros
``actions/node.py`` eb66680, ``parameter_descriptions.py`` 5314b3d,
``utilities/evaluate_parameters.py`` c176ada, ``normalize_parameters.py`` 25a4a39,
``ros2launch/api/api.py`` f2f3cbb; launch ``actions/declare_launch_argument.py`` dcc3487,
``actions/include_launch_description.py`` a3102a8, ``utilities/type_utils.py`` 3ff8fcf)
named in its docstring:

- :class:`LaunchDescription` (``launch.LaunchDescription``): an ordered list of entities,
  ``get_launch_arguments()``;
- :class:`LaunchContext` (``launch.LaunchContext``): ``launch_configurations``, ``argv``,
  ``locals.current_launch_file_path``;
- :class:`Substitution`, :class:`TextSubstitution`, :func:`perform_substitutions`,
  :func:`normalize_to_list_of_substitutions` (``launch.substitution``,
  ``launch.utilities``);
- :func:`coerce_to_type` (``launch.utilities.type_utils.coerce_to_type``): ``int(text)``,
  ``float(text)``, ``str``, YAML booleans, YAML rules without a type;
- ``launch.actions.DeclareLaunchArgument`` and ``OpaqueFunction`` (returning no entities),
  ``launch.substitutions.LaunchConfiguration`` and
  ``PathJoinSubstitution`` (their modules);
- ``launch_ros.actions.Node``, ``launch_ros.parameter_descriptions.ParameterValue``,
  ``launch_ros.substitutions.FindPackageShare`` (package ``launch_ros`` next to this one);
- ``ros2launch_stub`` (``ros2launch.api``): ``ros2 launch`` itself: argument parsing
  (``name:=value``, last one wins, unknown names are set and simply unused), the required
  argument check of ``IncludeLaunchDescription``, then each entity executed in order.

Anything else is refused: importing a name these modules do not define raises
:class:`UnsupportedByStub` (an ``ImportError``), and a keyword argument or value type the
stand-in does not implement raises :class:`UnsupportedByStub` too, so a launch-file edit
that uses more of the API fails the test until the stand-in (checked against the Jazzy
source) covers it.
"""

from __future__ import annotations

import importlib
import importlib.abc
import sys
import types
from typing import Any, Dict, Iterable, List, Optional

import yaml


class UnsupportedByStub(ImportError, NotImplementedError):
    """A part of the launch API the test stand-in does not implement (extend it first)."""


class SubstitutionFailure(RuntimeError):
    """A substitution could not be performed (``launch.substitutions.SubstitutionFailure``)."""


def refuse_missing(module: str, name: str) -> UnsupportedByStub:
    """
    The error for a name a stand-in module does not define.

    Parameters
    ----------
    module : str
        The module, e.g. ``'launch.actions'``.
    name : str
        The missing name.

    Returns
    -------
    UnsupportedByStub
        The exception to raise.
    """
    return UnsupportedByStub(
        f'{module}.{name} is not implemented by the test stand-in test/launch_stub; '
        'implement it there as the Jazzy source does before using it in a launch file')


def refuse_keywords(what: str, kwargs: Dict[str, Any]) -> None:
    """
    Refuse keyword arguments the stand-in does not implement.

    Parameters
    ----------
    what : str
        The class, for the message.
    kwargs : dict
        The keywords left over.

    Raises
    ------
    UnsupportedByStub
        If there are any.
    """
    if kwargs:
        raise UnsupportedByStub(
            f'{what}({", ".join(sorted(kwargs))}=...) is not implemented by the test '
            'stand-in test/launch_stub')


class LaunchContext:
    """
    The launch configurations (``launch.LaunchContext``) and what the run produced.

    ``argv`` holds the launch arguments of the command line (``LaunchService(argv=...)``);
    ``locals.current_launch_file_path`` the file being launched (``IncludeLaunchDescription``).
    """

    def __init__(self, argv: Optional[List[str]] = None) -> None:
        self.argv: List[str] = list(argv or [])
        self.locals = types.SimpleNamespace()
        self.launch_configurations: Dict[str, str] = {}
        #: Warnings the real tool logs (e.g. a parameter file that is not a file).
        self.warnings: List[str] = []
        #: Every ``LaunchConfiguration`` name performed, in order.
        self.configurations_used: List[str] = []


class Substitution:
    """Base class of substitutions (``launch.Substitution``)."""

    def perform(self, context: LaunchContext) -> str:
        """
        Evaluate the substitution.

        Parameters
        ----------
        context : LaunchContext
            The launch context.

        Returns
        -------
        str
            The text.
        """
        raise NotImplementedError

    def describe(self) -> str:
        """
        Describe the substitution (as ``ros2 launch --show-args`` prints defaults).

        Returns
        -------
        str
            A human-readable description.
        """
        return repr(self)


class TextSubstitution(Substitution):
    """Literal text (``launch.substitutions.TextSubstitution``)."""

    def __init__(self, *, text: str) -> None:
        if not isinstance(text, str):
            raise TypeError(f'TextSubstitution text must be str, got {type(text).__name__}')
        self.text = text

    def perform(self, context: LaunchContext) -> str:
        """Return the text."""
        return self.text

    def describe(self) -> str:
        """Return the quoted text."""
        return f"'{self.text}'"


def normalize_to_list_of_substitutions(subs: Any) -> List[Substitution]:
    """
    Normalize text, a substitution or an iterable of both (``launch.utilities``).

    Parameters
    ----------
    subs : str, Substitution or iterable of them
        What to normalize.

    Returns
    -------
    list of Substitution
        The substitutions.

    Raises
    ------
    TypeError
        For anything else.
    """
    def one(x: Any) -> Substitution:
        if isinstance(x, str):
            return TextSubstitution(text=x)
        if isinstance(x, Substitution):
            return x
        raise TypeError(f'Failed to normalize given item of type {type(x).__name__!r} '
                        'to a Substitution')

    if isinstance(subs, (str, Substitution)):
        return [one(subs)]
    if isinstance(subs, Iterable):
        return [one(x) for x in subs]
    raise TypeError(f'expected str, Substitution or an iterable of them, got {subs!r}')


def perform_substitutions(context: LaunchContext, subs: List[Substitution]) -> str:
    """
    Perform substitutions and concatenate their text (``launch.utilities``).

    Parameters
    ----------
    context : LaunchContext
        The launch context.
    subs : list of Substitution
        The substitutions.

    Returns
    -------
    str
        The concatenation.
    """
    return ''.join(s.perform(context) for s in subs)


def is_substitution(x: Any) -> bool:
    """
    Whether ``x`` is a substitution or a mixed list of text and substitutions.

    Parameters
    ----------
    x : object
        What to check.

    Returns
    -------
    bool
        ``launch.utilities.type_utils.is_substitution``.
    """
    if isinstance(x, Substitution):
        return True
    return (isinstance(x, (list, tuple)) and len(x) > 0
            and all(isinstance(i, (Substitution, str)) for i in x)
            and any(isinstance(i, Substitution) for i in x))


SCALAR_TYPES = (int, float, bool, str)


def coerce_to_type(value: str, data_type: Optional[type] = None) -> Any:
    """
    Coerce text to a type as ``launch.utilities.type_utils.coerce_to_type`` does.

    Parameters
    ----------
    value : str
        The text.
    data_type : type, optional
        ``int``, ``float``, ``bool``, ``str`` or None (YAML rules, scalar result).

    Returns
    -------
    int, float, bool or str
        The value.

    Raises
    ------
    ValueError
        If the text does not convert (``int('1.5')``, ``float('abc')``, ...).
    UnsupportedByStub
        For list types, which the stand-in does not implement.
    """
    if not isinstance(value, str):
        raise TypeError(f"'value' must be str, got {type(value).__name__}")

    def as_yaml(text: str, error: str) -> Any:
        if not text:
            return text
        try:
            output = yaml.safe_load(text)
        except yaml.YAMLError as err:
            raise ValueError(f'{error}: yaml.safe_load() failed\n{err}') from err
        if isinstance(output, list):
            raise UnsupportedByStub('list values are not implemented by the test stand-in')
        if not isinstance(output, SCALAR_TYPES):
            raise ValueError(f'{error}: output type is not allowed, got {type(output)}')
        return output

    if data_type is None:
        return as_yaml(value, f"Failed to convert '{value}' using yaml rules")
    if data_type not in SCALAR_TYPES:
        raise UnsupportedByStub(f'value_type {data_type!r} is not implemented by the test '
                                'stand-in (scalar int, float, bool, str only)')
    if data_type is str:
        return value
    if data_type in (int, float):
        return data_type(value)
    if value == '1':
        value = 'true'
    elif value == '0':
        value = 'false'
    output = as_yaml(value, f"Failed to convert '{value}' to '{data_type}'")
    if isinstance(output, bool):
        return output
    raise ValueError(f"Cannot convert value '{value}' to '{data_type}'")


class LaunchDescription:
    """
    An ordered list of launch entities (``launch.LaunchDescription``).

    Parameters
    ----------
    initial_entities : iterable, optional
        ``DeclareLaunchArgument`` and ``launch_ros.actions.Node`` actions; anything else
        is refused.
    **kwargs
        Refused (``deprecated_reason`` is not implemented).
    """

    def __init__(self, initial_entities: Optional[Iterable[Any]] = None, **kwargs: Any) -> None:
        refuse_keywords('LaunchDescription', kwargs)
        self.entities: List[Any] = []
        for entity in initial_entities or []:
            self.add_action(entity)

    def add_action(self, action: Any) -> None:
        """
        Append an action.

        Parameters
        ----------
        action : Action
            ``DeclareLaunchArgument`` or ``launch_ros.actions.Node``.

        Raises
        ------
        UnsupportedByStub
            For any other entity.
        """
        if not getattr(action, 'STUB_ACTION', False):
            raise UnsupportedByStub(f'launch entity {action!r} is not implemented by the test '
                                    'stand-in (DeclareLaunchArgument and Node only)')
        self.entities.append(action)

    def get_launch_arguments(self) -> List[Any]:
        """
        The declared launch arguments, in order.

        Returns
        -------
        list of DeclareLaunchArgument
            The declarations.
        """
        return [e for e in self.entities if getattr(e, 'IS_LAUNCH_ARGUMENT', False)]


#: Every module of the stand-in; importing any other ``launch.*``/``launch_ros.*`` is refused.
MODULES = ('launch.actions', 'launch.substitutions', 'launch_ros.actions',
           'launch_ros.parameter_descriptions', 'launch_ros.substitutions')


class RefuseOtherModules(importlib.abc.MetaPathFinder):
    """Refuse the modules of the real packages that the stand-in does not have."""

    def find_spec(self, fullname: str, path: Any, target: Any = None) -> None:
        """Raise :class:`UnsupportedByStub` for an unknown launch or launch_ros module."""
        if fullname.split('.')[0] in ('launch', 'launch_ros') and '.' in fullname \
                and fullname not in MODULES:
            package, _, name = fullname.rpartition('.')
            raise refuse_missing(package, name)
        return None


if not any(isinstance(f, RefuseOtherModules) for f in sys.meta_path):
    sys.meta_path.insert(0, RefuseOtherModules())


def __getattr__(name: str) -> Any:
    if name.startswith('__'):
        raise AttributeError(name)
    if name in ('actions', 'substitutions'):
        return importlib.import_module(f'launch.{name}')
    raise refuse_missing('launch', name)
