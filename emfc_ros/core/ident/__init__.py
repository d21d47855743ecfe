"""
System identification of the EMFC balance (no ROS imports).

Frequency responses (Welch H1/H2/Hv, periodic averaging, ETFE, selected frequencies, two
inputs), static characteristics, transfer-function and modal fits, grey-box parameter
estimation with least squares or pattern search, and fit metrics. See
``docs/identification.md``.
"""

from emfc_ros.core.ident.errors import IdentificationError, IllConditionedFitWarning
from emfc_ros.core.ident.frf import (cross_spectra, estimate_frf, FrequencyResponseData,
                                     Spectra)
from emfc_ros.core.ident.greybox import (DataSection, fit_greybox, GreyboxResult,
                                         ParameterSpec, SectionFit, specs_from_mapping)
from emfc_ros.core.ident.metrics import (CorrelationTest, fit_percent,
                                         input_correlation_test, whiteness_test)
from emfc_ros.core.ident.mimo import estimate_two_input_frf, TwoInputResponse
from emfc_ros.core.ident.modal import Mode
from emfc_ros.core.ident.pattern_search import (pattern_search, PatternSearchOptions,
                                                PatternSearchResult)
from emfc_ros.core.ident.periodic import average_periods, etfe, period_spectra
from emfc_ros.core.ident.single_frequency import response_at
from emfc_ros.core.ident.static_fit import (fit_motor_coefficient, fit_polynomial,
                                            linear_least_squares, LinearFit,
                                            MotorCoefficientFit, plateau_means, Plateaus,
                                            PolynomialFit)
from emfc_ros.core.ident.tf_fit import (fit_transfer_function, OrderSelection, select_order,
                                        TransferFunctionFit)

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
