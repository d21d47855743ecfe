"""The balance parameter file: read a ``balance.yaml``, or the shipped default."""

from __future__ import annotations

from typing import Optional

from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.paths import config_file

#: The shipped balance file (``config/``), the checked default parameter set.
DEFAULT_BALANCE_FILE = 'balance_default.yaml'


def load_balance(path: Optional[str] = None) -> BalanceParameters:
    """
    Balance parameters from a YAML file, or the shipped defaults.

    Parameters
    ----------
    path : str, optional
        A ``balance.yaml``; ``config/balance_default.yaml`` when None or empty.

    Returns
    -------
    BalanceParameters
        The parameters.

    Raises
    ------
    OSError
        If the file cannot be read.
    ConfigError
        If it is not a valid balance file (the message names the key).
    """
    return BalanceParameters.load_yaml(path if path else config_file(DEFAULT_BALANCE_FILE))
