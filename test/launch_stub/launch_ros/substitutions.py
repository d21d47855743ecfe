"""Stand-in for ``launch_ros.substitutions``: ``FindPackageShare`` (see ``launch``)."""

from __future__ import annotations

from typing import Any

from ament_index_python.packages import get_package_share_directory
from launch import (LaunchContext, normalize_to_list_of_substitutions, perform_substitutions,
                    refuse_missing, Substitution)


class FindPackageShare(Substitution):
    """
    A package's share directory (``launch_ros.substitutions.FindPackageShare``).

    Resolved with ``ament_index_python.get_package_share_directory`` as the real one is: the
    first prefix on ``AMENT_PREFIX_PATH`` with the package's marker, plus ``share/<package>``.

    Parameters
    ----------
    package : str, Substitution or list of them
        The package name.
    """

    def __init__(self, package: Any) -> None:
        self.package = normalize_to_list_of_substitutions(package)

    def perform(self, context: LaunchContext) -> str:
        """The share directory (``PackageNotFoundError`` if the package is not found)."""
        return get_package_share_directory(perform_substitutions(context, self.package))

    def describe(self) -> str:
        """Describe as the real class does."""
        return 'FindPackageShare(pkg=' + ' + '.join(s.describe() for s in self.package) + ')'


def __getattr__(name: str) -> Any:
    if name.startswith('__'):
        raise AttributeError(name)
    raise refuse_missing('launch_ros.substitutions', name)
