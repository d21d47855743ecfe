"""Stand-in for ``launch.substitutions``: two substitutions (see ``launch``)."""

from __future__ import annotations

import os
from typing import Any, Iterable

from launch import (LaunchContext, normalize_to_list_of_substitutions, perform_substitutions,
                    refuse_keywords, refuse_missing, Substitution, SubstitutionFailure,
                    TextSubstitution)

__all__ = ['LaunchConfiguration', 'PathJoinSubstitution', 'SubstitutionFailure',
           'TextSubstitution']


class LaunchConfiguration(Substitution):
    """
    The value of a launch configuration (``launch.substitutions.LaunchConfiguration``).

    Parameters
    ----------
    variable_name : str, Substitution or list of them
        The configuration's name.
    **kwargs
        Refused (``default`` is not implemented).
    """

    def __init__(self, variable_name: Any, **kwargs: Any) -> None:
        refuse_keywords('LaunchConfiguration', kwargs)
        self.variable_name = normalize_to_list_of_substitutions(variable_name)

    def perform(self, context: LaunchContext) -> str:
        """
        The configuration's value.

        Parameters
        ----------
        context : LaunchContext
            The launch context.

        Returns
        -------
        str
            The value.

        Raises
        ------
        SubstitutionFailure
            ``launch configuration '<name>' does not exist`` (an undeclared one not given).
        """
        name = perform_substitutions(context, self.variable_name)
        context.configurations_used.append(name)
        if name not in context.launch_configurations:
            raise SubstitutionFailure(f"launch configuration '{name}' does not exist")
        return context.launch_configurations[name]

    def describe(self) -> str:
        """Describe as the real class does."""
        return 'LaunchConfig(' + ' + '.join(s.describe() for s in self.variable_name) + ')'


class PathJoinSubstitution(Substitution):
    """
    ``os.path.join`` of the performed components (``launch.substitutions``).

    Parameters
    ----------
    substitutions : iterable
        Path components: text, substitutions, or lists of them.
    """

    def __init__(self, substitutions: Iterable[Any]) -> None:
        self.substitutions = [normalize_to_list_of_substitutions(c) for c in substitutions]

    def perform(self, context: LaunchContext) -> str:
        """Join the performed components."""
        return os.path.join(*[perform_substitutions(context, c) for c in self.substitutions])

    def describe(self) -> str:
        """Describe as the real class does."""
        return 'PathJoin(' + ', '.join(
            ' + '.join(s.describe() for s in c) for c in self.substitutions) + ')'


def __getattr__(name: str) -> Any:
    if name.startswith('__'):
        raise AttributeError(name)
    raise refuse_missing('launch.substitutions', name)
