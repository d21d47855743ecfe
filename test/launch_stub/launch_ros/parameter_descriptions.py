"""Stand-in for ``launch_ros.parameter_descriptions``: ``ParameterValue`` (see ``launch``)."""

from __future__ import annotations

from typing import Any, Optional

from launch import (coerce_to_type, is_substitution, LaunchContext,
                    normalize_to_list_of_substitutions, perform_substitutions, refuse_missing,
                    SCALAR_TYPES, UnsupportedByStub)


class ParameterValue:
    """
    A typed parameter value (``launch_ros.parameter_descriptions.ParameterValue`` of Jazzy).

    Parameters
    ----------
    value : scalar, Substitution or list of text and substitutions
        The value; a substitution is performed, then coerced to ``value_type``.
    value_type : type, optional
        ``int``, ``float``, ``bool`` or ``str``; None: YAML rules (list types are refused).
    """

    def __init__(self, value: Any, *, value_type: Optional[type] = None) -> None:
        if value_type is not None and value_type not in SCALAR_TYPES:
            raise UnsupportedByStub(f'ParameterValue value_type {value_type!r} is not '
                                    'implemented by the test stand-in')
        if isinstance(value, SCALAR_TYPES):
            if value_type is not None and not isinstance(value, value_type):
                raise TypeError(f"value '{value}' is not an instance of {value_type}")
            self.value = value
        elif is_substitution(value):
            self.value = normalize_to_list_of_substitutions(value)
        else:
            raise UnsupportedByStub(f'ParameterValue({value!r}) is not implemented by the '
                                    'test stand-in (scalars and substitutions only)')
        self.value_type = value_type

    def evaluate(self, context: LaunchContext) -> Any:
        """
        Perform and coerce (``perform_typed_substitution``).

        Parameters
        ----------
        context : LaunchContext
            The launch context.

        Returns
        -------
        int, float, bool or str
            The typed value.

        Raises
        ------
        ValueError
            If the text does not convert to ``value_type``.
        """
        if not isinstance(self.value, list):
            return self.value
        return coerce_to_type(perform_substitutions(context, self.value), self.value_type)


def __getattr__(name: str) -> Any:
    if name.startswith('__'):
        raise AttributeError(name)
    raise refuse_missing('launch_ros.parameter_descriptions', name)
