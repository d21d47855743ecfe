"""Stand-in for ``launch.actions``: ``DeclareLaunchArgument`` only (see ``launch``)."""

from __future__ import annotations

from typing import Any, Optional

from launch import (LaunchContext, normalize_to_list_of_substitutions, perform_substitutions,
                    refuse_keywords, refuse_missing)


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
        Shown by ``ros2 launch --show-args`` (``'no description given'`` when absent).
    **kwargs
        Refused (``choices``, ``condition``, ... are not implemented).
    """

    STUB_ACTION = True
    IS_LAUNCH_ARGUMENT = True

    def __init__(self, name: str, *, default_value: Any = None,
                 description: Optional[str] = None, **kwargs: Any) -> None:
        refuse_keywords('DeclareLaunchArgument', kwargs)
        if not isinstance(name, str):
            raise TypeError('DeclareLaunchArgument name must be str')
        self.name = name
        self.default_value = (None if default_value is None
                              else normalize_to_list_of_substitutions(default_value))
        self.description = 'no description given' if description is None else description

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
            ``Required launch argument "<name>" was not provided.``
        """
        if self.name not in context.launch_configurations:
            if self.default_value is None:
                raise RuntimeError(f'Required launch argument "{self.name}" was not provided.')
            context.launch_configurations[self.name] = perform_substitutions(
                context, self.default_value)


def __getattr__(name: str) -> Any:
    if name.startswith('__'):
        raise AttributeError(name)
    raise refuse_missing('launch.actions', name)
