"""Stand-in for ``launch.actions``: DeclareLaunchArgument, OpaqueFunction (see ``launch``)."""

from __future__ import annotations

from typing import Any, Callable, Dict, Iterable, List, Optional

from launch import (LaunchContext, normalize_to_list_of_substitutions, perform_substitutions,
                    refuse_keywords, refuse_missing, UnsupportedByStub)


class DeclareLaunchArgument:
    """
    A launch argument (``launch.actions.DeclareLaunchArgument`` of Jazzy).

    Parameters
    ----------
    name : str
        The argument and launch configuration name.
    default_value : str, Substitution or list of them, optional
        The default; without one the argument is required.
    description : str, optional
        Shown by ``ros2 launch --show-args`` (``'no description given'`` when absent;
        with ``choices`` the real class appends ``Valid choices are: [...]``).
    choices : list of str, optional
        The values allowed; an empty list, or a plain-text default not among them, is an
        error at once; a value given (or defaulted) outside them is an error at launch.
    **kwargs
        Refused (``condition``, ... are not implemented).
    """

    STUB_ACTION = True
    IS_LAUNCH_ARGUMENT = True

    def __init__(self, name: str, *, default_value: Any = None,
                 description: Optional[str] = None, choices: Optional[List[str]] = None,
                 **kwargs: Any) -> None:
        refuse_keywords('DeclareLaunchArgument', kwargs)
        if not isinstance(name, str):
            raise TypeError('DeclareLaunchArgument name must be str')
        if choices is not None:
            if len(choices) == 0:
                raise RuntimeError('Provided choices arg is empty. Use None to ignore the '
                                   'choice list.')
            if isinstance(default_value, str) and default_value not in choices:
                raise RuntimeError(f'Provided default_value "{default_value}" is not in '
                                   f'provided choices "{choices}".')
        self.name = name
        self.choices = None if choices is None else list(choices)
        self.default_value = (None if default_value is None
                              else normalize_to_list_of_substitutions(default_value))
        if description is None:
            description = ('no description given' if choices is None
                           else f'One of: {self.choices}')
        elif choices is not None:
            description = (description if description.endswith('.') else description + '.') \
                + f' Valid choices are: {self.choices}'
        self.description = description

    def execute(self, context: LaunchContext) -> None:
        """
        Set the default unless the argument was given; a missing required one is an error.

        Parameters
        ----------
        context : LaunchContext
            The launch context.

        Raises
        ------
        RuntimeError
            ``Required launch argument "<name>" was not provided.``, or ``Argument "<name>"
            provided value "<value>" is not valid. Valid options are: [...]``.
        """
        if self.name not in context.launch_configurations:
            if self.default_value is None:
                raise RuntimeError(f'Required launch argument "{self.name}" was not provided.')
            context.launch_configurations[self.name] = perform_substitutions(
                context, self.default_value)
        value = context.launch_configurations[self.name]
        if self.choices is not None and value not in self.choices:
            raise RuntimeError(f'Argument "{self.name}" provided value "{value}" is not valid. '
                               f'Valid options are: {self.choices}')


class OpaqueFunction:
    """
    Call a function at launch time (``launch.actions.OpaqueFunction`` of Jazzy).

    Parameters
    ----------
    function : callable
        Called as ``function(context, *args, **kwargs)``; may raise to end the launch.
    args : iterable, optional
        Positional arguments after the context.
    kwargs : dict, optional
        Keyword arguments.
    **other
        Refused.
    """

    STUB_ACTION = True

    def __init__(self, *, function: Callable, args: Optional[Iterable[Any]] = None,
                 kwargs: Optional[Dict[str, Any]] = None, **other: Any) -> None:
        refuse_keywords('OpaqueFunction', other)
        if not callable(function):
            raise TypeError("OpaqueFunction expected a callable for 'function'")
        self.function = function
        self.args = list(args or [])
        self.kwargs = dict(kwargs or {})

    def execute(self, context: LaunchContext) -> None:
        """
        Call the function.

        Parameters
        ----------
        context : LaunchContext
            The launch context.

        Raises
        ------
        UnsupportedByStub
            If it returns entities (the stand-in launches none from a function).
        """
        entities = self.function(context, *self.args, **self.kwargs)
        if entities:
            raise UnsupportedByStub('entities returned by an OpaqueFunction are not '
                                    'implemented by the test stand-in')


def __getattr__(name: str) -> Any:
    if name.startswith('__'):
        raise AttributeError(name)
    raise refuse_missing('launch.actions', name)
