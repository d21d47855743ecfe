"""
System identification of the EMFC balance (no ROS imports).

Frequency responses (Welch H1/H2/Hv, periodic averaging, ETFE, selected frequencies, two
inputs), static characteristics, transfer-function and modal fits, grey-box parameter
estimation with least squares or pattern search, and fit metrics. See
``docs/identification.md``.
"""

from emfc_ros.core.ident.errors import IdentificationError, IllConditionedFitWarning
from emfc_ros.core.lazy_names import lazy_getattr

#: Public names and the submodule that holds each: imported on first use (PEP 562), so that
#: importing a light submodule (the plan check's :mod:`~emfc_ros.core.ident.pipeline_config`)
#: does not import scipy.signal and scipy.stats with the frequency-response modules.
_LAZY = {
    'cross_spectra': 'frf', 'estimate_frf': 'frf', 'FrequencyResponseData': 'frf',
    'Spectra': 'frf', 'DataSection': 'greybox', 'fit_greybox': 'greybox',
    'GreyboxResult': 'greybox', 'ParameterSpec': 'greybox', 'SectionFit': 'greybox',
    'specs_from_mapping': 'greybox', 'CorrelationTest': 'metrics', 'fit_percent': 'metrics',
    'input_correlation_test': 'metrics', 'whiteness_test': 'metrics',
    'estimate_two_input_frf': 'mimo', 'TwoInputResponse': 'mimo', 'Mode': 'modal',
    'PatternSearchOptions': 'pattern_search', 'PatternSearchResult': 'pattern_search',
    'average_periods': 'periodic', 'etfe': 'periodic', 'period_spectra': 'periodic',
    'response_at': 'single_frequency', 'fit_motor_coefficient': 'static_fit',
    'fit_polynomial': 'static_fit', 'linear_least_squares': 'static_fit',
    'LinearFit': 'static_fit', 'MotorCoefficientFit': 'static_fit',
    'plateau_means': 'static_fit', 'Plateaus': 'static_fit', 'PolynomialFit': 'static_fit',
    'fit_transfer_function': 'tf_fit', 'OrderSelection': 'tf_fit',
    'select_order': 'tf_fit', 'TransferFunctionFit': 'tf_fit'}

# The function shares its submodule's name: bound now, so that importing the submodule
# (which sets the package attribute) can never shadow it (numpy only, light).
from emfc_ros.core.ident.pattern_search import pattern_search  # noqa: E402,I100


__getattr__ = lazy_getattr(__name__, _LAZY, globals())


__all__ = [
    'average_periods', 'CorrelationTest', 'cross_spectra', 'DataSection', 'estimate_frf',
    'estimate_two_input_frf', 'etfe', 'fit_greybox', 'fit_motor_coefficient', 'fit_percent',
    'fit_polynomial', 'fit_transfer_function', 'FrequencyResponseData', 'GreyboxResult',
    'IdentificationError', 'IllConditionedFitWarning', 'input_correlation_test',
    'linear_least_squares', 'LinearFit', 'Mode', 'MotorCoefficientFit', 'OrderSelection',
    'ParameterSpec', 'pattern_search', 'PatternSearchOptions', 'PatternSearchResult',
    'period_spectra', 'plateau_means', 'Plateaus', 'PolynomialFit', 'response_at', 'SectionFit',
    'select_order', 'Spectra', 'specs_from_mapping', 'TransferFunctionFit', 'TwoInputResponse',
    'whiteness_test',
]
